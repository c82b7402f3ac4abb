"""Hostile OpenCRG inputs through the commands that read or write OpenCRG: ``compose --surface
crg:FILE`` and ``sweep --surface crg:FILE`` (read) and ``export --format crg`` (write).

The corpus is built here by mutating the shipped files in ``tests/data/opencrg`` (truncation,
wrong counts and types, NaN/inf, huge values, empty files, directories where files are expected,
``$ROAD_CRG_FILE`` reference cycles and missing targets, paths with spaces and non-ASCII
characters). Every case must end in exit 0, or exit 2 with exactly one line on stderr naming the
input; never a traceback or "internal error", never a partial output (no OUT, no temporary files
beside it; an earlier export stays byte-identical), never a changed input. Warnings a run would
print count as stderr lines. The CLI runs in-process (``roadtwin_core.cli.main``, same code path
as the console script) to keep the corpus fast; one case also runs as a real subprocess.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "opencrg"
STRAIGHT = (DATA / "handmade_straight.crg").read_text("latin-1")
CURVED = (DATA / "handmade_curved.crg").read_text("latin-1")
BELGIAN = (DATA / "belgian_block.crg").read_bytes()


# ----------------------------------------------------------------------------------------- helpers
def run_cli(args: list[str], capfd) -> tuple[int, list[str]]:
    """Run ``roadtwin ARGS`` in-process; (exit code, stderr lines incl. warnings it would print)."""
    from roadtwin_core.cli import main

    capfd.readouterr()
    argv = sys.argv
    sys.argv = ["roadtwin", *args]
    code = 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        finally:
            sys.argv = argv
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    lines += [f"warning: {w.message}" for w in caught]
    return code, lines


def snapshot(folder: Path, skip: Path | None = None) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and (skip is None or skip not in p.parents)}


def replace_once(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def data_lines(text: str) -> tuple[str, list[str]]:
    start = text.index("\n$$$$") + 1
    end = text.index("\n", start) + 1
    return text[:end], text[end:].splitlines()


def set_field(text: str, row: int, col: int, value: str, width: int = 10) -> str:
    """Replace the fixed-width field ``col`` of data record ``row`` (LRFI: 10 characters)."""
    head, rows = data_lines(text)
    line = rows[row].ljust((col + 1) * width)
    rows[row] = line[:col * width] + value.rjust(width) + line[(col + 1) * width:]
    return head + "\n".join(rows) + "\n"


def binary(name: str, double: bool, d: Path) -> bytes:
    """The shipped text file ``name`` as KRBI / KDBI bytes (roadtwin's writer; input only)."""
    from roadtwin_opencrg import read_crg, write_crg

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        crg = read_crg(DATA / name)
    return write_crg(d / "_bin.crg", crg, binary=True, double=double).read_bytes()


def ref(name: str, mods: str = "") -> str:
    out = f"$CT\nreferencing file\n$!\n$ROAD_CRG_FILE   ! the data\n {name}\n$!\n"
    return out + (f"$ROAD_CRG_MODS\n{mods}\n$!\n" if mods else "")


# ----------------------------------------------------------------------------------------- corpus
# Each builder gets a fresh case folder and returns the CRG path to give the command; the error
# line must name that path. "ok": must exit 0; "err": must exit 2; "any": either.
def _w(d: Path, name: str, content: str | bytes) -> Path:
    p = d / name
    p.parent.mkdir(parents=True, exist_ok=True)
    (p.write_bytes if isinstance(content, bytes) else lambda c: p.write_text(c, "latin-1"))(content)
    return p


def _dir(d: Path) -> Path:
    (d / "road.crg").mkdir()
    return d / "road.crg"


def _cycle2(d: Path) -> Path:
    _w(d, "b.crg", ref("a.crg"))
    return _w(d, "a.crg", ref("b.crg"))


def _deep(d: Path) -> Path:
    for k in range(12):
        _w(d, f"r{k}.crg", ref(f"r{k + 1}.crg"))
    _w(d, "r12.crg", STRAIGHT)
    return d / "r0.crg"


def _spaces(d: Path) -> Path:
    _w(d, "road data/é straight.crg", STRAIGHT)
    # the name split over two lines (and comments), as the standard allows; MODS override
    text = ("$ROAD_CRG_FILE\n road data/ ! folder\n* a comment line\n é straight.crg\n$!\n"
            "$ROAD_CRG_MODS\n GRID_NAN_MODE = 1\n$!\n")
    return _w(d, "top ü.crg", text.encode("utf-8"))


def _fortran(d: Path) -> Path:
    t = replace_once(STRAIGHT, "REFERENCE_LINE_INCREMENT = 1.0", "REFERENCE_LINE_INCREMENT = 1.0D+00")
    t = set_field(t, 3, 2, "1.11111D-2")
    t = set_field(t, 4, 3, "nan")
    return _w(d, "fortran.crg", t)


def _krbi(d: Path, cut: int = 0, poke: float | None = None, nan_all: bool = False) -> Path:
    raw = binary("handmade_curved.crg", False, d)
    head_len = raw.index(b"$$$$")
    head_len = raw.index(b"\n", head_len) + 1
    vals = np.frombuffer(raw[head_len:], dtype=">f4").copy()
    if poke is not None:
        vals[8 * 3 + 4] = poke
    if nan_all:
        vals[:] = np.nan
    body = vals.tobytes()
    out = raw[:head_len] + (body[:len(body) - cut] if cut else body)
    (d / "_bin.crg").unlink()
    return _w(d, "curved.krbi.crg", out)


def _kdbi_short(d: Path) -> Path:
    raw = binary("handmade_straight.crg", True, d)
    (d / "_bin.crg").unlink()
    return _w(d, "straight.kdbi.crg", raw[:-300])


S = STRAIGHT
READ_CASES = {
    # empty / not files / not CRG
    "empty-file": ("err", lambda d: _w(d, "empty.crg", "")),
    "blank-lines": ("err", lambda d: _w(d, "blank.crg", "\n \n\t\n")),
    "directory": ("err", _dir),
    "missing-file": ("err", lambda d: d / "nope.crg"),
    "random-bytes": ("err", lambda d: _w(d, "noise.crg", np.random.default_rng(0).bytes(4096))),
    "nul-bytes": ("err", lambda d: _w(d, "nul.crg", set_field(S, 1, 2, "0.01\0\0\0"))),
    "header-only": ("err", lambda d: _w(d, "head.crg", S[:S.index("$$$$")])),
    # truncation and wrong counts
    "truncated-half": ("err", lambda d: _w(d, "half.crg", S[:len(S) // 2])),
    "truncated-in-row": ("err", lambda d: _w(d, "cut.crg", S.rstrip("\n")[:-25] + "\n")),
    "rows-missing": ("err", lambda d: _w(d, "rows.crg", "\n".join(S.splitlines()[:-3]) + "\n")),
    "row-extra-value": ("err", lambda d: _w(d, "extra.crg", S.rstrip("\n") + " 0.0000000\n")),
    "channel-def-missing": ("err", lambda d: _w(d, "chan.crg", S.replace("D:long section 7,m", "", 1))),
    "no-channels": ("err", lambda d: _w(d, "noch.crg", "\n".join(
        ln for ln in S.splitlines() if not ln.startswith("D:")) + "\n")),
    "no-kd-definition": ("err", lambda d: _w(d, "nokd.crg", S.replace("$KD_Definition", "$KD_Nothing", 1))),
    "no-format-line": ("err", lambda d: _w(d, "nofmt.crg", S.replace("#:LRFI", "", 1))),
    "format-krfi": ("err", lambda d: _w(d, "krfi.crg", S.replace("#:LRFI", "#:KRFI", 1))),
    "format-lrbi": ("err", lambda d: _w(d, "lrbi.crg", S.replace("#:LRFI", "#:LRBI", 1))),
    "binary-read-as-text": ("err", lambda d: _w(d, "bb.crg", BELGIAN.replace(b"#:KRBI", b"#:LRFI", 1))),
    "text-read-as-binary": ("any", lambda d: _w(d, "tb.crg", S.replace("#:LRFI", "#:KRBI", 1))),
    # wrong types, NaN / inf, huge and tiny values in the header and the data
    "cell-inf": ("err", lambda d: _w(d, "inf.crg", set_field(S, 2, 3, "inf"))),
    "cell-huge": ("err", lambda d: _w(d, "huge.crg", set_field(S, 2, 3, "1.0e+30"))),
    "cell-word": ("err", lambda d: _w(d, "word.crg", set_field(S, 2, 3, "pothole"))),
    "increment-nan": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                   "REFERENCE_LINE_INCREMENT = nan", 1))),
    "increment-inf": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                   "REFERENCE_LINE_INCREMENT = inf", 1))),
    "increment-zero": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                    "REFERENCE_LINE_INCREMENT = 0.0", 1))),
    "increment-negative": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                        "REFERENCE_LINE_INCREMENT = -1.0", 1))),
    "increment-tiny": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                    "REFERENCE_LINE_INCREMENT = 1e-300", 1))),
    "increment-word": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                    "REFERENCE_LINE_INCREMENT = one", 1))),
    "increment-decimal-comma": ("err", lambda d: _w(d, "inc.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                             "REFERENCE_LINE_INCREMENT = 0,5", 1))),
    "end-u-huge": ("err", lambda d: _w(d, "endu.crg", S.replace("REFERENCE_LINE_END_U     = 22.0",
                                                                 "REFERENCE_LINE_END_U     = 1e11", 1))),
    "start-x-huge": ("err", lambda d: _w(d, "x.crg", S.replace("REFERENCE_LINE_START_X   = 0.0",
                                                                "REFERENCE_LINE_START_X   = 1e300", 1))),
    "v-increment-tiny": ("err", lambda d: _w(d, "vinc.crg", S.replace("LONG_SECTION_V_INCREMENT = 0.50",
                                                                       "LONG_SECTION_V_INCREMENT = 1e-9", 1))),
    "nan-mode-0": ("err", lambda d: _w(d, "nan0.crg", replace_once(
        S, "$KD_Definition", "$ROAD_CRG_MODS\nGRID_NAN_MODE = 0\n$\n$KD_Definition"))),
    "nan-mode-7": ("err", lambda d: _w(d, "nan7.crg", replace_once(
        S, "$KD_Definition", "$ROAD_CRG_MODS\nGRID_NAN_MODE = 7\n$\n$KD_Definition"))),
    "key-without-value": ("err", lambda d: _w(d, "kv.crg", S.replace("REFERENCE_LINE_INCREMENT = 1.0",
                                                                      "REFERENCE_LINE_INCREMENT", 1))),
    # binary data: short, inf, all missing
    "krbi-short": ("err", lambda d: _krbi(d, cut=150)),
    "krbi-inf": ("err", lambda d: _krbi(d, poke=np.inf)),
    "krbi-huge": ("err", lambda d: _krbi(d, poke=3e38)),
    "krbi-all-missing": ("err", lambda d: _krbi(d, nan_all=True)),
    "kdbi-short": ("err", _kdbi_short),
    "belgian-truncated": ("err", lambda d: _w(d, "bb.crg", BELGIAN[:len(BELGIAN) // 3])),
    # $ROAD_CRG_FILE references
    "ref-self-cycle": ("err", lambda d: _w(d, "self.crg", ref("self.crg"))),
    "ref-two-cycle": ("err", _cycle2),
    "ref-too-deep": ("err", _deep),
    "ref-missing-target": ("err", lambda d: _w(d, "top.crg", ref("gone.crg"))),
    "ref-target-directory": ("err", lambda d: (d / "sub.crg").mkdir() or _w(d, "top.crg", ref("sub.crg"))),
    "ref-target-not-crg": ("err", lambda d: _w(d, "notes.txt", "just notes\n") and _w(d, "top.crg", ref("notes.txt"))),
    "ref-target-truncated": ("err", lambda d: _w(d, "half.crg", S[:len(S) // 2]) and _w(d, "top.crg", ref("half.crg"))),
    "ref-and-data": ("err", lambda d: _w(d, "d.crg", S) and _w(d, "top.crg", ref("d.crg") + S)),
    "ref-empty-name": ("err", lambda d: _w(d, "top.crg", "$ROAD_CRG_FILE\n! nothing\n$!\n")),
    "ref-unset-env": ("err", lambda d: _w(d, "top.crg", ref("$ROADTWIN_NO_SUCH_VARIABLE/x.crg"))),
    "ref-bad-mods": ("err", lambda d: _w(d, "d.crg", S) and _w(d, "top.crg", ref("d.crg", "GRID_NAN_MODE = two"))),
    # readable oddities: exit 0
    "ok-ref-spaces-nonascii": ("ok", _spaces),
    "ok-fortran-numbers-nan-cell": ("ok", _fortran),
    "ok-crlf": ("ok", lambda d: _w(d, "crlf.crg", S.replace("\n", "\r\n"))),
}
FAST = {k: v for k, v in READ_CASES.items() if v[0] != "ok"}


@pytest.fixture(scope="module")
def layout(tmp_path_factory) -> Path:
    """A 20 m x 7 m one-segment driving layout (centred on y = 0, where the CRGs lie)."""
    from pxr import Sdf, Usd, UsdGeom

    path = tmp_path_factory.mktemp("layout") / "layout.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Town").GetPrim()
    stage.SetDefaultPrim(root)
    root.CreateAttribute("roadtwin:rules:defectCount", Sdf.ValueTypeNames.Int, custom=True).Set(2)
    UsdGeom.Xform.Define(stage, "/Town/Roads")
    mesh = UsdGeom.Mesh.Define(stage, "/Town/Roads/seg0")
    mesh.CreatePointsAttr([(0, -3.5, 0), (20, -3.5, 0), (20, 3.5, 0), (0, 3.5, 0)])
    mesh.CreateFaceVertexCountsAttr([3, 3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 0, 2, 3])
    mesh.GetPrim().CreateAttribute("roadtwin:segment:kind", Sdf.ValueTypeNames.Token, custom=True).Set("driving")
    centerline = mesh.GetPrim().CreateAttribute("roadtwin:segment:centerline", Sdf.ValueTypeNames.Float2Array,
                                                custom=True)
    centerline.Set([(0.0, 0.0), (20.0, 0.0)])
    stage.GetRootLayer().Save()
    return path


def check_outcome(code: int, lines: list[str], expect: str, name: str) -> None:
    text = "\n".join(lines)
    assert "Traceback" not in text and "internal error" not in text, text
    if expect == "ok":
        assert code == 0, text
    elif expect == "err":
        assert code == 2, text
    else:
        assert code in (0, 2), text
    if code == 2:
        assert len(lines) == 1, text
        assert name in lines[0], (name, lines[0])


def _case_dir(tmp_path: Path) -> Path:
    d = tmp_path / "case"
    d.mkdir()
    return d


def _run_read_case(cmd: str, case: str, tmp_path: Path, layout: Path, capfd) -> None:
    expect, build = READ_CASES[case]
    d = _case_dir(tmp_path)
    crg = build(d)
    before = snapshot(d)
    out = tmp_path / "out"
    if cmd == "compose":
        args = ["compose", str(layout), "-o", str(out), "--surface", f"crg:{crg}", "--executor", "serial",
                "--no-preview", "--seed", "1"]
    else:
        args = ["sweep", "-o", str(out), "--surface", f"crg:{crg}", "--speeds", "20", "--length", "10",
                "--no-plots"]
    code, lines = run_cli(args, capfd)
    check_outcome(code, lines, expect, crg.name)
    assert snapshot(d) == before, "input changed"
    if code != 0:
        assert not out.exists(), "partial output"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")], "temporary output left"


@pytest.mark.parametrize("case", list(READ_CASES), ids=[f"compose-{c}" for c in READ_CASES])
def test_compose_surface_crg(case, tmp_path, layout, capfd):
    _run_read_case("compose", case, tmp_path, layout, capfd)


SWEEP_CASES = ["directory", "truncated-in-row", "cell-inf", "ref-two-cycle", "ref-missing-target", "krbi-short"]


@pytest.mark.parametrize("case", SWEEP_CASES, ids=[f"sweep-{c}" for c in SWEEP_CASES])
def test_sweep_surface_crg(case, tmp_path, layout, capfd):
    _run_read_case("sweep", case, tmp_path, layout, capfd)


def test_compose_reference_cycle_real_process(tmp_path, layout):
    """The same rule through the console entry point in a real process (one case)."""
    crg = _cycle2(_case_dir(tmp_path))
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    proc = subprocess.run([sys.executable, "-m", "roadtwin_core.cli", "compose", str(layout), "-o",
                           str(tmp_path / "out"), "--surface", f"crg:{crg}", "--no-preview"],
                          capture_output=True, text=True, env=env, timeout=300)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "reference cycle" in lines[0] and "a.crg" in lines[0] and "b.crg" in lines[0]
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------------------- export
@pytest.fixture(scope="module")
def town(tmp_path_factory, layout) -> Path:
    from roadtwin_core.apps.compose.run import compose

    out = tmp_path_factory.mktemp("crgtown") / "town"
    return compose(layout, out, defects=2, seed=3, preview=False, surface="flat", executor="serial").town


def _stage_dir(d: Path, town: Path) -> Path:
    (d / "town.usda").mkdir()
    return d / "town.usda"


def _copy_town(d: Path, town: Path, mutate=None, layout: bool = True) -> Path:
    dst = d / "town"
    shutil.copytree(town.parent, dst, ignore=None if layout else shutil.ignore_patterns("layout"))
    if mutate is not None:
        (dst / "town.usda").write_bytes(mutate((dst / "town.usda").read_bytes()))
    return dst / "town.usda"


# (expect, build(d, town) -> (stage, out), name the error line must contain: "stage" or "out")
EXPORT_CASES = {
    "out-is-directory": ("err", lambda d, t: (t, (d / "lane.crg").mkdir() or d / "lane.crg"), "out"),
    "out-parent-missing": ("err", lambda d, t: (t, d / "no" / "such" / "lane.crg"), "out"),
    "stage-directory": ("err", lambda d, t: (_stage_dir(d, t), d / "lane.crg"), "stage"),
    "stage-empty-file": ("err", lambda d, t: (_copy_town(d, t, lambda b: b""), d / "lane.crg"), "stage"),
    "stage-truncated": ("err", lambda d, t: (_copy_town(d, t, lambda b: b[:len(b) // 2]), d / "lane.crg"), "stage"),
    "stage-garbage": ("err", lambda d, t: (_copy_town(d, t, lambda b: b"#usda 1.0\n(( not usd\n"), d / "lane.crg"),
                      "stage"),
    "stage-without-layout": ("err", lambda d, t: (_copy_town(d, t, layout=False), d / "lane.crg"), "stage"),
    "ok-out-spaces-nonascii": ("ok", lambda d, t: (t, (d / "my roads é").mkdir() or d / "my roads é" / "läne 1.crg"),
                               "out"),
}


@pytest.mark.parametrize("case", list(EXPORT_CASES), ids=[f"export-{c}" for c in EXPORT_CASES])
def test_export_crg(case, tmp_path, town, capfd):
    expect, build, who = EXPORT_CASES[case]
    d = _case_dir(tmp_path)
    stage, out = build(d, town)
    town_before = snapshot(town.parent)
    before = snapshot(d)
    code, lines = run_cli(["export", str(stage), "--format", "crg", "-o", str(out)], capfd)
    check_outcome(code, lines, expect, (stage if who == "stage" else out).name)
    assert snapshot(town.parent) == town_before, "input changed"
    after = snapshot(d)
    if code != 0:
        assert after == before, "partial output"
    else:
        from roadtwin_opencrg import read_crg

        assert set(after) - set(before) == {str(out.relative_to(d))}
        assert read_crg(out).fmt == "KRBI"
    assert not [p for p in out.parent.glob(".*tmp*")] if out.parent.exists() else True


def test_export_replaces_earlier_output_whole(tmp_path, town, capfd):
    """An export over an earlier file replaces it (exit 0); a failing one leaves it byte-identical."""
    out = tmp_path / "lane.crg"
    out.write_bytes(b"earlier output\n")
    code, lines = run_cli(["export", str(town), "--format", "crg", "-o", str(out)], capfd)
    assert code == 0, lines
    good = out.read_bytes()
    assert good.startswith(b"$CT")
    bad = _copy_town(_case_dir(tmp_path), town, layout=False)
    code, lines = run_cli(["export", str(bad), "--format", "crg", "-o", str(out)], capfd)
    assert code == 2 and len(lines) == 1 and bad.name in lines[0]
    assert out.read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case", "lane.crg"]
