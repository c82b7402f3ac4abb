"""Bad input through the real CLI: exit code 2, exactly one line on stderr naming the file, prim
or parameter at fault, no traceback, and nothing written: an earlier output at the same ``-o``
stays byte-identical and no temporary directory is left beside it.

The bad layouts are small USD files built here with pxr (or written as text); a good 20 m x 7 m
one-segment layout is composed once into OUT first (flat surface, no preview: about a second).
Argument-parsing errors that click itself reports (``--seed abc``, unknown options, missing
arguments) follow the same rule: one line, exit 2. The cases go through the CLI's entry point in
this process (``cli_run.run_main``); two of them, the usage errors and the output-is-a-file case
also through a fresh interpreter, as a user runs it, and every case does with ``-m slow``.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from cli_run import run_main
from pxr import Sdf, Usd, UsdGeom

REPO = Path(__file__).resolve().parents[2]
D, I, S = Sdf.ValueTypeNames.Double, Sdf.ValueTypeNames.Int, Sdf.ValueTypeNames.String
SEG = "/Town/Roads/seg0"


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    return subprocess.run([sys.executable, "-m", "roadtwin_core.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def run_here(*args: str, cwd: Path, capsys, monkeypatch) -> subprocess.CompletedProcess:
    """:func:`run_cli` through the entry point in this process (``cli_run.run_main``)."""
    monkeypatch.chdir(cwd)
    code, out, err = run_main(list(args), capsys, monkeypatch)
    return subprocess.CompletedProcess(list(args), code, out, err)


def write_layout(path: Path, *, points=None, faces=None, counts=None, up: str = "Z", mpu: float = 1.0,
                 rules: dict | None = None, segment: bool = True) -> Path:
    """A one-segment layout (a 20 m x 7 m driving lane unless told otherwise)."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, up)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    root = UsdGeom.Xform.Define(stage, "/Town").GetPrim()
    stage.SetDefaultPrim(root)
    rules = {"defectCount": (I, 4), "surface": (S, "flat"), **(rules or {})}
    for key, (vtype, value) in rules.items():
        root.CreateAttribute(f"roadtwin:rules:{key}", vtype, custom=True).Set(value)
    UsdGeom.Xform.Define(stage, "/Town/Roads")
    if segment:
        points = points if points is not None else [(0, 0, 0), (20, 0, 0), (20, 7, 0), (0, 7, 0)]
        faces = faces if faces is not None else [(0, 1, 2), (0, 2, 3)]
        mesh = UsdGeom.Mesh.Define(stage, SEG)
        mesh.CreatePointsAttr([tuple(float(c) for c in p) for p in points])
        mesh.CreateFaceVertexCountsAttr(counts or [len(f) for f in faces])
        mesh.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
        mesh.GetPrim().CreateAttribute("roadtwin:segment:kind", Sdf.ValueTypeNames.Token, custom=True).Set("driving")
    stage.GetRootLayer().Save()
    return path


def snapshot(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Bad (and one good) inputs, and OUT: an earlier successful compose of good.usda."""
    d = tmp_path_factory.mktemp("cli")
    write_layout(d / "good.usda")
    (d / "notes.txt").write_text("road notes, not USD\n")
    (d / "garbage.usda").write_text("this is {{ not usd at all\n")
    write_layout(d / "yup.usda", up="Y")
    write_layout(d / "centimeters.usda", mpu=0.01)
    write_layout(d / "nosegments.usda", segment=False)
    # All points on one line: every triangle has zero area.
    write_layout(d / "collinear.usda", points=[(0, 0, 0), (5, 0, 0), (10, 0, 0), (15, 0, 0)],
                 faces=[(0, 1, 2), (1, 2, 3)])
    # Two triangles overlapping each other.
    write_layout(d / "overlap.usda", points=[(0, 0, 0), (10, 0, 0), (0, 10, 0), (2, 2, 0), (12, 2, 0), (2, 12, 0)],
                 faces=[(0, 1, 2), (3, 4, 5)])
    # A bow-tie quad (its outline crosses itself), authored as one polygon.
    write_layout(d / "bowtie.usda", points=[(0, 0, 0), (10, 10, 0), (10, 0, 0), (0, 10, 0)], faces=[(0, 1, 2, 3)])
    # Two triangles meeting only at one vertex: not one polygon.
    write_layout(d / "pinched.usda", points=[(0, 0, 0), (0, 10, 0), (5, 5, 0), (10, 0, 0), (10, 10, 0)],
                 faces=[(0, 2, 1), (2, 3, 4)])
    write_layout(d / "nanpoint.usda", points=[(0, 0, 0), (20, 0, 0), (20, float("nan"), 0), (0, 7, 0)])
    # Topology that does not add up: counts vs indices, an index past the points, a 2-gon.
    write_layout(d / "countmismatch.usda", counts=[3, 4])
    write_layout(d / "indexrange.usda", faces=[(0, 1, 2), (0, 2, 9)])
    write_layout(d / "twogon.usda", faces=[(0, 1), (0, 1, 2, 3)])
    write_layout(d / "nanspacing.usda", rules={"spacingM": (D, float("nan"))})
    write_layout(d / "negedge.usda", rules={"roadEdgeM": (D, -0.5)})
    write_layout(d / "textspacing.usda", rules={"spacingM": (S, "wide")})
    write_layout(d / "unknownrule.usda", rules={"colour": (S, "red")})
    (d / "a_file").write_text("not a directory\n")
    # Props rules (layers/props.usda): one that fits nothing, a file that is not TOML, an unknown prototype.
    (d / "giant.toml").write_text('[[rule]]\nname = "giant_poles"\ngroup = "Poles"\nprototypes = {utility_pole = 1}\n'
                                  'spacing_m = 100000\n')
    (d / "badrules.toml").write_text("[[rule]\n")
    (d / "palms.toml").write_text('[[rule]]\nname = "palms"\ngroup = "Palms"\nprototypes = {tree_palm = 1}\n')
    r = run_cli("compose", "good.usda", "-o", "OUT", "--no-preview", cwd=d)
    assert r.returncode == 0, r.stderr
    assert (d / "OUT" / "town.usda").is_file()
    return d


# (id, command-line arguments, regexes the one stderr line must match)
CASES = [
    ("missing-file", ["compose", "no[such]file.usda"], [r"no\[such\]file\.usda", "no such file"]),
    ("text-file", ["compose", "notes.txt"], [r"notes\.txt", "not a USD file"]),
    ("garbage-usda", ["compose", "garbage.usda"], [r"garbage\.usda", "not a USD file"]),
    ("y-up", ["compose", "yup.usda"], [r"yup\.usda", "upAxis", "Z"]),
    ("centimeters", ["compose", "centimeters.usda"], [r"centimeters\.usda", "metersPerUnit", "0.01"]),
    ("no-segments", ["compose", "nosegments.usda"], [r"nosegments\.usda", "no road segments"]),
    ("degenerate", ["compose", "collinear.usda"], [r"collinear\.usda", SEG, "degenerate"]),
    ("overlapping", ["compose", "overlap.usda"], [r"overlap\.usda", SEG, "overlap|self-intersect"]),
    ("bow-tie", ["compose", "bowtie.usda"], [r"bowtie\.usda", SEG, "overlap|self-intersect"]),
    ("pinched", ["compose", "pinched.usda"], [r"pinched\.usda", SEG, "not one connected polygon"]),
    ("nan-point", ["compose", "nanpoint.usda"], [r"nanpoint\.usda", SEG, "NaN"]),
    ("count-mismatch", ["compose", "countmismatch.usda"], [r"countmismatch\.usda", SEG, "add up to 7", "6 entries"]),
    ("index-range", ["compose", "indexrange.usda"], [r"indexrange\.usda", SEG, "point 9", "4 points"]),
    ("two-gon", ["compose", "twogon.usda"], [r"twogon\.usda", SEG, "2 vertices"]),
    ("nan-rule", ["compose", "nanspacing.usda"], [r"nanspacing\.usda", "spacing", "nan"]),
    ("text-rule", ["compose", "textspacing.usda"], [r"textspacing\.usda", "roadtwin:rules:spacingM"]),
    ("unknown-rule", ["compose", "unknownrule.usda"], [r"unknownrule\.usda", "roadtwin:rules:colour"]),
    ("negative-rule", ["compose", "negedge.usda"], [r"negedge\.usda", "road_?[eE]dge", "-0.5"]),
    ("nan-surface", ["compose", "good.usda", "--surface", "iso8608:C:nan"], ["surface", "nan"]),
    ("negative-defects", ["compose", "good.usda", "--defects", "-5"], ["defect count", "-5"]),
    ("negative-seed", ["compose", "good.usda", "--seed", "-1"], ["seed", "-1"]),
    ("too-many-defects", ["compose", "good.usda", "--defects", "100000"],
     [r"good\.usda", r"only \d+ of 100000 defects fit"]),
    ("unknown-merger", ["compose", "good.usda", "--merger", "nope"], ["merger", "'nope'", "cdt"]),
    ("unknown-surface-class", ["compose", "good.usda", "--surface", "iso8608:Q"], ["surface", "'Q'", "A..H"]),
    ("unknown-surface", ["compose", "good.usda", "--surface", "bumpy"], ["surface", "'bumpy'"]),
    ("props-fit-nothing", ["compose", "good.usda", "--props", "giant.toml"],
     [r"good\.usda", "props rule 'giant_poles' fits nothing", "spacing 100000 m is longer than every road outline"]),
    ("props-missing", ["compose", "good.usda", "--props", "nosuch.toml"], [r"nosuch\.toml", "props rules file not found"]),
    ("props-not-toml", ["compose", "good.usda", "--props", "badrules.toml"], [r"badrules\.toml", "not a TOML"]),
    ("props-unknown-prototype", ["compose", "good.usda", "--props", "palms.toml"],
     [r"palms\.toml", "'palms'", "unknown prototype 'tree_palm'"]),
]


def check_one_line(r: subprocess.CompletedProcess, patterns: list[str]) -> str:
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 2, f"exit {r.returncode}: {r.stderr}"
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and r.stderr.endswith("\n"), f"stderr is not one line: {r.stderr!r}"
    line = lines[0]
    assert line.startswith("error: "), line
    for pat in patterns:
        assert re.search(pat, line), f"{pat!r} not in {line!r}"
    return line


IN_A_PROCESS_BY_DEFAULT = {"missing-file", "props-fit-nothing"}


@pytest.mark.parametrize("args,patterns", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_keeps_earlier_output(work, args, patterns, capsys, monkeypatch):
    keeps_earlier_output(work, lambda: run_here(*args, "-o", "OUT", cwd=work, capsys=capsys, monkeypatch=monkeypatch),
                         patterns)


@pytest.mark.parametrize("args,patterns", [
    pytest.param(*c[1:], id=c[0], marks=() if c[0] in IN_A_PROCESS_BY_DEFAULT else pytest.mark.slow) for c in CASES])
def test_bad_input_in_a_fresh_process_keeps_earlier_output(work, args, patterns):
    keeps_earlier_output(work, lambda: run_cli(*args, "-o", "OUT", cwd=work), patterns)


def keeps_earlier_output(work: Path, run, patterns: list[str]) -> None:
    """``run()`` (a bad command) prints its one line and leaves OUT and the folder as they were."""
    before = snapshot(work / "OUT")
    listing = sorted(p.name for p in work.iterdir())
    check_one_line(run(), patterns)
    assert snapshot(work / "OUT") == before, "the earlier output changed"
    assert sorted(p.name for p in work.iterdir()) == listing, "files were left beside the output"


NO_OUTPUT = {"missing-file", "bow-tie", "nan-surface", "too-many-defects", "props-fit-nothing"}


@pytest.mark.parametrize("args,patterns", [c[1:] for c in CASES if c[0] in NO_OUTPUT],
                         ids=[c[0] for c in CASES if c[0] in NO_OUTPUT])
def test_bad_input_creates_no_output(work, args, patterns, capsys, monkeypatch):
    r = run_here(*args, "-o", "fresh/OUT2", cwd=work, capsys=capsys, monkeypatch=monkeypatch)
    check_one_line(r, patterns)
    assert not (work / "fresh" / "OUT2").exists()
    assert not (work / "fresh").exists() or not any((work / "fresh").iterdir())


def test_output_path_is_a_file(work):
    before = (work / "a_file").read_bytes()
    r = run_cli("compose", "good.usda", "-o", "a_file", "--no-preview", cwd=work)
    check_one_line(r, [r"a_file", "not a directory"])
    assert (work / "a_file").read_bytes() == before


@pytest.mark.parametrize("args, names", [
    (["compose", "stages/town.usda", "--seed", "abc", "-o", "OUT"], "'--seed'"),
    (["compose", "stages/town.usda", "--bogus"], "--bogus"),
    (["compose"], "'layout'"),
    (["render", "stages/town.usda", "-o", "OUT", "--frames", "abc"], "'--frames'"),
    (["no-such-command"], "'no-such-command'"),
])
def test_usage_errors_are_one_line_and_exit_2(tmp_path, args, names):
    """click's own errors (bad values, unknown options and commands, missing arguments) are the
    user's mistake: exit 2, one line naming the option, no 'internal error', no output."""
    args = [str(tmp_path / "out") if a == "OUT" else (str(REPO / a) if a.startswith("stages/") else a) for a in args]
    r = run_cli(*args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and names in lines[0], r.stderr
    assert "internal error" not in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()
