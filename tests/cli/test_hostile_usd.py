"""Hostile input through the real CLI for the commands that read USD: ``compose``, ``validate``,
``export``, ``library`` (and ``import``'s output side).

The corpus is built here from the shipped samples (``stages/town.usda``,
``stages/defect_avoidance.usda``) and from a town composed once through the CLI (its
``town.usda``, layers and ``library/``), by mutating them: truncation, wrong types, NaN/inf,
out-of-range and huge values, a 10 km segment of millions of triangles, empty files, directories
where files belong, non-USD files, unresolvable sublayers/references/payloads, sublayer cycles,
unwritable outputs (an output whose parent is a regular file: chmod does not stop root) and
paths with spaces and non-ASCII characters (the whole corpus lives in such a folder).

Every case runs ``roadtwin_core.cli.main`` in-process (the same code as the console script,
minus the interpreter start) with stdout/stderr captured at the file-descriptor level, so USD's
own C++ warnings count too. Each case must end in exit 0, or exit 2 with exactly one stderr line
that names the input at fault; never a traceback or "internal error"; no input file changed
(hashed before and after); no partial output (the output absent, or an earlier output at the same
path byte-identical, and no temporary litter beside it). ``validate`` may also exit 1 when the
stage reads but ``pxr.UsdValidation`` reports errors: that is its report, not a failure.

Case counts per command: ``pytest --collect-only -q tests/cli/test_hostile_usd.py | grep -c compose``
(ids are ``<command>-<case>``), or ``python tests/cli/test_hostile_usd.py``.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

REPO = Path(__file__).resolve().parents[2]
STAGES = REPO / "stages"
FLAGS = ["--executor", "serial", "--no-preview"]


# --------------------------------------------------------------------------------------------
# corpus


@dataclass
class Case:
    argv: list[str]
    names: str                          # what the one error line must mention (a path's name, an option)
    output: Path | None = None          # must be absent or unchanged after a failure
    codes: tuple[int, ...] = (0, 2)
    env: dict[str, str] = field(default_factory=dict)
    scratch: Path | None = None         # where the command may write besides output (not an input)


class Corpus:
    """Shared, read-only inputs; each case makes its own files in ``case_dir``."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.inputs = root / "inputs dir ü"
        self.inputs.mkdir()
        self.layout = self.inputs / "small road ø.usda"
        _tiny_layout(self.layout)
        self.earlier = root / "earlier out"             # an earlier output: must survive failures
        self.earlier.mkdir()
        (self.earlier / "summary.json").write_text('{"earlier": true}\n')
        self.composed = root / "composed town é"
        code, out, err = _run(["compose", str(self.layout), "-o", str(self.composed), "--defects", "2",
                               "--seed", "3", *FLAGS])
        assert code == 0, err
        self.town = self.composed / "town.usda"
        self.library = self.composed / "library"
        self.asset = next(p for p in sorted(self.library.glob("*.usda")) if not p.name.endswith(".geom.usda"))

    def case_dir(self, name: str) -> Path:
        d = self.root / "cases" / f"{name} ä"
        d.mkdir(parents=True, exist_ok=True)
        return d


def _tiny_layout(path: Path, *, points=None, faces=None, rules: dict | None = None, header: str = "",
                 mutate: Callable[[Usd.Stage], None] | None = None) -> Path:
    """A one-segment layout (a 30 m x 7 m driving lane) with a flat surface."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Town").GetPrim()
    stage.SetDefaultPrim(root)
    values = {"defectCount": (Sdf.ValueTypeNames.Int, 2), "surface": (Sdf.ValueTypeNames.String, "flat"),
              **(rules or {})}
    for key, (vtype, value) in values.items():
        root.CreateAttribute(f"roadtwin:rules:{key}", vtype, custom=True).Set(value)
    UsdGeom.Xform.Define(stage, "/Town/Roads")
    mesh = UsdGeom.Mesh.Define(stage, "/Town/Roads/seg0")
    pts = np.asarray(points if points is not None else [(0, 0, 0), (30, 0, 0), (30, 7, 0), (0, 7, 0)], np.float32)
    tri = np.asarray(faces if faces is not None else [(0, 1, 2), (0, 2, 3)], np.int32).reshape(-1, 3)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tri), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(tri.ravel()))
    mesh.GetPrim().CreateAttribute("roadtwin:segment:kind", Sdf.ValueTypeNames.Token, custom=True).Set("driving")
    if mutate:
        mutate(stage)
    stage.GetRootLayer().Save()
    if header:
        text = path.read_text()
        path.write_text(text.replace("(\n", f"(\n    {header}\n", 1))
    return path


def _truncate(src: Path, dst: Path, share: float) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * share)])
    return dst


def _text_sub(src: Path, dst: Path, pattern: str, repl: str) -> Path:
    text, n = re.subn(pattern, repl, src.read_text(), count=1)
    assert n == 1, f"{pattern!r} not in {src.name}"
    dst.write_text(text)
    return dst


def _first_point(src: Path, dst: Path, value: str) -> Path:
    """The first coordinate of the first ``points`` array replaced by ``value``."""
    return _text_sub(src, dst, r"(point3f\[\] points = \[\()(-?[0-9.e+-]+)", rf"\g<1>{value}")


def _over(dst: Path, base: Path, body: str) -> Path:
    """A layer that sublayers ``base`` and overrides something in it (the input stays untouched)."""
    dst.write_text(f'#usda 1.0\n(\n    defaultPrim = "Town"\n    metersPerUnit = 1\n    upAxis = "Z"\n'
                   f'    subLayers = [@{base.as_posix()}@]\n)\n\n{body}\n')
    return dst


def _first_mesh_path(stage_path: Path, under: str = "Roads") -> str:
    stage = Usd.Stage.Open(str(stage_path))
    return next(str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and f"/{under}/" in str(p.GetPath()))


def _over_prim(prim_path: str, body: str) -> str:
    """``over`` blocks down to ``prim_path`` with ``body`` inside the last one."""
    parts = prim_path.strip("/").split("/")
    text = body
    for name in reversed(parts):
        text = f'over "{name}" {{\n{text}\n}}'
    return text


def _asset_copy(c: Corpus, d: Path) -> Path:
    """The composed library's first asset (interface + geometry) copied into ``d``."""
    shutil.copy(c.asset, d / c.asset.name)
    geom = c.asset.with_name(c.asset.stem + ".geom.usda")
    shutil.copy(geom, d / geom.name)
    return d / c.asset.name


def _geom_of(asset: Path) -> Path:
    return asset.with_name(asset.stem + ".geom.usda")


# --------------------------------------------------------------------------------------------
# cases: name -> builder(corpus, case_dir) -> Case

def compose_case(layout_of: Callable[[Corpus, Path], Path], names: str | None = None, *extra: str,
                 out: str = "earlier", env: dict | None = None):
    def build(c: Corpus, d: Path) -> Case:
        layout = layout_of(c, d)
        target = c.earlier if out == "earlier" else d / out
        return Case(["compose", str(layout), "-o", str(target), *FLAGS, *extra],
                    names if names is not None else layout.name, target, env=env or {})
    return build


def _mkdir(d: Path, name: str) -> Path:
    (d / name).mkdir(exist_ok=True)
    return d / name


def _write(d: Path, name: str, data: bytes | str) -> Path:
    p = d / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return p


def _wrong_points(c: Corpus, d: Path) -> Path:
    """The segment's points authored as strings (USD refuses to author that through the schema)."""
    return _text_sub(_tiny_layout(d / "strpoints.usda"), d / "strpoints.usda", r"point3f\[\] points = \[[^\]]*\]",
                     'string[] points = ["a", "b", "c"]')


def _xform_segment(stage: Usd.Stage) -> None:
    prim = UsdGeom.Xform.Define(stage, "/Town/Roads/seg1").GetPrim()
    prim.CreateAttribute("roadtwin:segment:kind", Sdf.ValueTypeNames.Token, custom=True).Set("driving")


def _ref(kind: str) -> Callable[[Usd.Stage], None]:
    def mutate(stage: Usd.Stage) -> None:
        prim = stage.GetPrimAtPath("/Town/Roads/seg0")
        if kind == "reference":
            prim.GetReferences().AddReference("./no such file.usda", "/X")
        else:
            prim.GetPayloads().AddPayload("./no such payload.usdc")
    return mutate


def _strip_layout(c: Corpus, d: Path, n: int, length: float, name: str) -> Path:
    """A segment ``length`` m long and 7 m wide, ``2 n`` triangles in a strip."""
    x = np.linspace(0.0, length, n + 1)
    pts = np.concatenate([np.column_stack([x, np.zeros_like(x), np.zeros_like(x)]),
                          np.column_stack([x, np.full_like(x, 7.0), np.zeros_like(x)])])
    i = np.arange(n)
    faces = np.concatenate([np.column_stack([i, i + 1, i + n + 2]), np.column_stack([i, i + n + 2, i + n + 1])])
    return _tiny_layout(d / name, points=pts, faces=faces)


# One triangle whose first coordinate is {}; counts and indices match it.
TRI = "point3f[] points = [({}, 0, 0), (1, 0, 0), (0, 1, 0)]\nint[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, 1, 2]"
I, S, D = Sdf.ValueTypeNames.Int, Sdf.ValueTypeNames.String, Sdf.ValueTypeNames.Double
TOWN, AVOID = STAGES / "town.usda", STAGES / "defect_avoidance.usda"

COMPOSE: dict[str, Callable[[Corpus, Path], Case]] = {
    "empty-file": compose_case(lambda c, d: _write(d, "empty.usda", b"")),
    "truncated-town": compose_case(lambda c, d: _truncate(TOWN, d / "town cut.usda", 0.4)),
    "truncated-avoidance": compose_case(lambda c, d: _truncate(AVOID, d / "avoid cut.usda", 0.7)),
    "truncated-tiny": compose_case(lambda c, d: _truncate(c.layout, d / "tiny cut.usda", 0.5)),
    "garbage-usdc": compose_case(lambda c, d: _write(d, "noise.usdc", np.random.default_rng(0).bytes(4096))),
    "garbage-usda": compose_case(lambda c, d: _write(d, "noise.usda", "#usda 1.0\n def Xform \"T\" {{{ \x00\n")),
    "not-usd-suffix": compose_case(lambda c, d: Path(shutil.copy(AVOID, d / "avoid.txt"))),
    "directory": compose_case(lambda c, d: _mkdir(d, "dir.usda")),
    "missing": compose_case(lambda c, d: d / "missing.usda"),
    "nan-point-town": compose_case(lambda c, d: _first_point(TOWN, d / "town nan.usda", "nan")),
    "inf-point-avoidance": compose_case(lambda c, d: _first_point(AVOID, d / "avoid inf.usda", "inf")),
    "huge-point-avoidance": compose_case(lambda c, d: _first_point(AVOID, d / "avoid huge.usda", "1e30")),
    "far-point": compose_case(lambda c, d: _tiny_layout(d / "far.usda", points=[(0, 0, 0), (3e7, 0, 0), (3e7, 7, 0), (0, 7, 0)])),
    "wrong-type-points": compose_case(_wrong_points),
    "wrong-type-rule": compose_case(lambda c, d: _tiny_layout(d / "strcount.usda", rules={"defectCount": (S, "many")})),
    "wrong-type-rule-text": compose_case(lambda c, d: _text_sub(AVOID, d / "avoid seed.usda", r"int roadtwin:rules:seed = 0", 'string roadtwin:rules:seed = "zero"')),
    "negative-count": compose_case(lambda c, d: _tiny_layout(d / "negcount.usda", rules={"defectCount": (I, -5)})),
    "negative-spacing": compose_case(lambda c, d: _tiny_layout(d / "negspacing.usda", rules={"spacingM": (D, -1.0)})),
    "nan-rule": compose_case(lambda c, d: _tiny_layout(d / "nanrule.usda", rules={"edgeMarginM": (D, float("nan"))})),
    "huge-count": compose_case(lambda c, d: _tiny_layout(d / "hugecount.usda", rules={"defectCount": (I, 2_000_000_000)})),
    "empty-mesh": compose_case(lambda c, d: _tiny_layout(d / "emptymesh.usda", points=np.zeros((0, 3)), faces=np.zeros((0, 3)))),
    "degenerate-mesh": compose_case(lambda c, d: _tiny_layout(d / "degenerate.usda", points=[(1, 1, 0)] * 4)),
    "index-out-of-range": compose_case(lambda c, d: _tiny_layout(d / "badindex.usda", faces=[(0, 1, 2), (0, 2, 99)])),
    "non-mesh-segment": compose_case(lambda c, d: _tiny_layout(d / "xformseg.usda", mutate=_xform_segment)),
    "missing-sublayer": compose_case(lambda c, d: _tiny_layout(d / "sub.usda", header="subLayers = [@./gone layer.usda@]")),
    "cyclic-sublayer": compose_case(lambda c, d: (_write(d, "b.usda", '#usda 1.0\n(\n    subLayers = [@./cyc.usda@]\n)\n'),
                                                  _tiny_layout(d / "cyc.usda", header="subLayers = [@./b.usda@]"))[1]),
    "missing-reference": compose_case(lambda c, d: _tiny_layout(d / "ref.usda", mutate=_ref("reference"))),
    "missing-payload": compose_case(lambda c, d: _tiny_layout(d / "payload.usda", mutate=_ref("payload"))),
    "y-up": compose_case(lambda c, d: _text_sub(AVOID, d / "avoid yup.usda", r'upAxis = "Z"', 'upAxis = "Y"')),
    "centimetres": compose_case(lambda c, d: _text_sub(AVOID, d / "avoid cm.usda", r"metersPerUnit = 1", "metersPerUnit = 0.01")),
    "no-default-prim": compose_case(lambda c, d: _text_sub(AVOID, d / "avoid nodefault.usda", r'defaultPrim = "Town"', 'defaultPrim = "Nowhere"')),
    "10km-of-1mm-triangles": compose_case(lambda c, d: _strip_layout(c, d, 1_100_000, 10_000.0, "strip.usdc")),
    "10km-segment-iso8608": compose_case(lambda c, d: _strip_layout(c, d, 1, 10_000.0, "long.usda"), "surface", "--surface", "iso8608:C:0.001"),
    "out-parent-is-file": compose_case(lambda c, d: c.layout, "blocker", out="blocker/out"),
    "out-is-file": compose_case(lambda c, d: c.layout, "out.txt", out="out.txt"),
    "library-is-file": compose_case(lambda c, d: c.layout, "lib.usda", "--library", "LIB:lib.usda"),
    "library-bad-asset": compose_case(lambda c, d: c.layout, "bad.usda", "--library", "LIB:badlib"),
    "seed-not-a-number": compose_case(lambda c, d: c.layout, "--seed", "--seed", "abc"),
}

VALIDATE = {
    "empty-file": lambda c, d: Case(["validate", str(_write(d, "empty.usda", b""))], "empty.usda"),
    "truncated-composed": lambda c, d: Case(["validate", str(_truncate(c.town, d / "town cut.usda", 0.5))], "town cut.usda"),
    "truncated-avoidance": lambda c, d: Case(["validate", str(_truncate(AVOID, d / "avoid cut.usda", 0.3))], "avoid cut.usda"),
    "garbage-usdc": lambda c, d: Case(["validate", str(_write(d, "noise.usdc", np.random.default_rng(1).bytes(999)))], "noise.usdc"),
    "not-usd-suffix": lambda c, d: Case(["validate", str(shutil.copy(AVOID, d / "avoid.json"))], "avoid.json"),
    "directory": lambda c, d: Case(["validate", str(_mkdir(d, "stage.usda"))], "stage.usda"),
    "missing": lambda c, d: Case(["validate", str(d / "missing.usda")], "missing.usda"),
    "missing-sublayer": lambda c, d: Case(["validate", str(_over(d / "over.usda", d / "gone.usda", ""))], "gone.usda"),
    "cyclic-sublayer": lambda c, d: Case(["validate", str((_write(d, "b.usda", '#usda 1.0\n(\n    subLayers = [@./a.usda@]\n)\n'),
                                                             _write(d, "a.usda", '#usda 1.0\n(\n    subLayers = [@./b.usda@]\n)\n'))[1])], "a.usda"),
    "missing-reference": lambda c, d: Case(["validate", str(_tiny_layout(d / "ref.usda", mutate=_ref("reference")))], "ref.usda"),
    "nan-points-over-composed": lambda c, d: Case(["validate", str(_over(d / "nan.usda", c.town, _over_prim(
        _first_mesh_path(c.town), TRI.format("nan"))))], "nan.usda"),
    "composed-town": lambda c, d: Case(["validate", str(c.town)], "town.usda"),
    "shipped-avoidance": lambda c, d: Case(["validate", str(AVOID)], "defect_avoidance.usda", codes=(0, 1, 2)),
    "y-up-avoidance": lambda c, d: Case(["validate", str(_text_sub(AVOID, d / "yup.usda", r'upAxis = "Z"', 'upAxis = "Y"'))],
                                        "yup.usda", codes=(0, 1, 2)),
}


def export_case(stage_of: Callable[[Corpus, Path], Path], names: str | None = None, fmt: str = "glb",
                out: str = "out ü.glb"):
    def build(c: Corpus, d: Path) -> Case:
        stage = stage_of(c, d)
        target = d / "exported" / out
        return Case(["export", str(stage), "-f", fmt, "-o", str(target)], names or stage.name, target,
                    scratch=d / "exported")
    return build


EXPORT = {
    **{f"composed-{fmt}": export_case(lambda c, d: c.town, fmt=fmt, out=f"town ü.{fmt}") for fmt in ("glb", "obj", "ply", "usdz")},
    "empty-file": export_case(lambda c, d: _write(d, "empty.usda", b"")),
    "truncated-composed": export_case(lambda c, d: _truncate(c.town, d / "town cut.usda", 0.6)),
    "garbage-usdc": export_case(lambda c, d: _write(d, "noise.usdc", b"PXR-USDC" + np.random.default_rng(2).bytes(500))),
    "not-usd-suffix": export_case(lambda c, d: Path(shutil.copy(c.town, d / "town.png"))),
    "directory": export_case(lambda c, d: _mkdir(d, "town.usda")),
    "missing": export_case(lambda c, d: d / "missing.usda"),
    "missing-sublayer": export_case(lambda c, d: _over(d / "over.usda", d / "gone.usda", ""), "gone.usda"),
    "nan-points": export_case(lambda c, d: _over(d / "nan.usda", c.town, _over_prim(
        _first_mesh_path(c.town), TRI.format("nan")))),
    "inf-points-ply": export_case(lambda c, d: _over(d / "inf.usda", c.town, _over_prim(
        _first_mesh_path(c.town), TRI.format("inf"))), fmt="ply", out="o.ply"),
    "bad-indices": export_case(lambda c, d: _over(d / "idx.usda", c.town, _over_prim(
        _first_mesh_path(c.town), "int[] faceVertexIndices = [0, 1, 99999]\nint[] faceVertexCounts = [3]"))),
    "counts-mismatch-obj": export_case(lambda c, d: _over(d / "cnt.usda", c.town, _over_prim(
        _first_mesh_path(c.town), "int[] faceVertexCounts = [3, 3, 3]")), fmt="obj", out="o.obj"),
    "wrong-type-points": export_case(lambda c, d: _over(d / "strpts.usda", c.town, _over_prim(
        _first_mesh_path(c.town), 'string[] points = ["a", "b", "c"]'))),
    "layout-not-composed-crg": export_case(lambda c, d: c.layout, "small road", fmt="crg", out="road.crg"),
    "out-parent-is-file": export_case(lambda c, d: c.town, "blocker", out="blocker/town.glb"),
    "out-is-directory": export_case(lambda c, d: c.town, "outdir.glb", out="outdir.glb"),
    "unknown-format": export_case(lambda c, d: c.town, "nosuch", fmt="nosuch"),
}


def library_case(verb: str, asset_of: Callable[[Corpus, Path], Path] | None, names: str,
                 folder: str | None = None, name: str | None = None):
    """``library list|show|add``; ``asset_of`` builds the asset (or folder) the case is about."""
    def build(c: Corpus, d: Path) -> Case:
        thing = asset_of(c, d) if asset_of else None
        if verb == "list":
            return Case(["library", "list", "-l", str(thing)], names)
        if verb == "show":
            return Case(["library", "show", name or thing.stem, "-l", str(thing.parent if thing.is_file() else thing)],
                        names)
        lib = d / (folder or "new library ñ")
        return Case(["library", "add", str(thing), "-l", str(lib)], names, output=lib)
    return build


def _lib_with(c: Corpus, d: Path, edit: Callable[[Path], None] | None = None) -> Path:
    folder = _mkdir(d, "lib ç")
    asset = _asset_copy(c, folder)
    if edit:
        edit(asset)
    return asset


def _edit_geom(pattern: str, repl: str) -> Callable[[Path], None]:
    return lambda asset: _text_sub(_geom_of(asset), _geom_of(asset), pattern, repl)


def _edit_iface(pattern: str, repl: str) -> Callable[[Path], None]:
    return lambda asset: _text_sub(asset, asset, pattern, repl)


LIBRARY = {
    "list-composed": library_case("list", lambda c, d: c.library, "library"),
    "list-missing-folder": library_case("list", lambda c, d: d / "nowhere", "nowhere"),
    "list-folder-is-file": library_case("list", lambda c, d: _write(d, "lib.usda", "x"), "lib.usda"),
    "list-corrupt-files": library_case("list", lambda c, d: (_write(_mkdir(d, "junk"), "a.usda", b""),
                                                              _write(d / "junk", "b.usdc", b"\x00" * 64), d / "junk")[-1], "junk"),
    "show-composed": library_case("show", lambda c, d: c.asset, "library"),
    "show-unknown-name": library_case("show", lambda c, d: c.library, "no_such_asset", name="no_such_asset"),
    "show-truncated-geometry": library_case("show", lambda c, d: _lib_with(c, d, lambda a: _truncate(_geom_of(a), _geom_of(a), 0.5)), ".geom.usda"),
    "show-missing-payload": library_case("show", lambda c, d: _lib_with(c, d, lambda a: _geom_of(a).unlink()), ".geom.usda"),
    "show-nan-geometry": library_case("show", lambda c, d: _lib_with(c, d, lambda a: _first_point(_geom_of(a), _geom_of(a), "nan")), ".usda"),
    "show-loop-out-of-range": library_case("show", lambda c, d: _lib_with(c, d, _edit_geom(
        r"int\[\] roadtwin:defect:boundaryLoop = \[[^\]]*\]", "int[] roadtwin:defect:boundaryLoop = [0, 1, 999999]")), "boundaryLoop"),
    "show-loop-wrong-type": library_case("show", lambda c, d: _lib_with(c, d, _edit_geom(
        r"int\[\] roadtwin:defect:boundaryLoop = \[[^\]]*\]", 'string roadtwin:defect:boundaryLoop = "loop"')), "boundaryLoop"),
    "show-params-not-json": library_case("show", lambda c, d: _lib_with(c, d, _edit_iface(
        r"string roadtwin:params = '.*'", 'string roadtwin:params = "{not json"')), "roadtwin:params"),
    "show-type-wrong-type": library_case("show", lambda c, d: _lib_with(c, d, _edit_iface(
        r'string roadtwin:defect:type = "[^"]*"', "double roadtwin:defect:type = 3.5")), "roadtwin:defect:type"),
    "show-geometry-is-points": library_case("show", lambda c, d: _lib_with(c, d, _edit_geom(r'def Mesh "mesh"', 'def Points "mesh"')), "Mesh"),
    "show-huge-values": library_case("show", lambda c, d: _lib_with(c, d, lambda a: _first_point(_geom_of(a), _geom_of(a), "1e35")), ".usda"),
    "add-composed": library_case("add", lambda c, d: c.asset, "added"),
    "add-truncated": library_case("add", lambda c, d: _truncate(c.asset, d / "cut ö.usda", 0.5), "cut ö.usda"),
    "add-empty": library_case("add", lambda c, d: _write(d, "empty.usda", b""), "empty.usda"),
    "add-directory": library_case("add", lambda c, d: _mkdir(d, "asset.usda"), "asset.usda"),
    "add-not-usd": library_case("add", lambda c, d: _write(d, "asset.obj", "v 0 0 0\n"), "asset.obj"),
    "add-layout-not-asset": library_case("add", lambda c, d: c.layout, "small road"),
    "add-missing-payload": library_case("add", lambda c, d: _lib_with(c, d, lambda a: _geom_of(a).unlink()), ".geom.usda"),
    "add-nan-geometry": library_case("add", lambda c, d: _lib_with(c, d, lambda a: _first_point(_geom_of(a), _geom_of(a), "-inf")), ".usda"),
    "add-into-file-parent": library_case("add", lambda c, d: c.asset, "blocker", folder="blocker/lib"),
}


def _import_case(out: str, names: str):
    def build(c: Corpus, d: Path) -> Case:
        src = REPO / "tests" / "data" / "opendrive" / "curved_road_default.xodr"
        return Case(["import", "opendrive", str(src), "-o", str(d / out)], names, output=d / out)
    return build


IMPORT = {
    "out-with-spaces": _import_case("out ü/road é.usda", "road"),
    "out-parent-is-file": _import_case("blocker/road.usda", "blocker"),
    "out-is-directory": _import_case("taken.usda", "taken.usda"),
    "out-not-usd-suffix": _import_case("road.xyz", "road.xyz"),
}

CASES = {"compose": COMPOSE, "validate": VALIDATE, "export": EXPORT, "library": LIBRARY, "import": IMPORT}


# --------------------------------------------------------------------------------------------
# running


def _run(argv: list[str], env: dict[str, str] | None = None) -> tuple[int, str, str]:
    """``roadtwin ARGV`` in-process; returns (exit code, stdout, stderr) captured at fd level."""
    import tempfile

    from roadtwin_core import cli

    saved_env = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    saved = sys.argv
    sys.stdout.flush(), sys.stderr.flush()
    with tempfile.TemporaryFile() as fo, tempfile.TemporaryFile() as fe:
        old_out, old_err = os.dup(1), os.dup(2)
        os.dup2(fo.fileno(), 1), os.dup2(fe.fileno(), 2)
        py_out, py_err = sys.stdout, sys.stderr
        sys.stdout = open(1, "w", closefd=False, encoding="utf-8")
        sys.stderr = open(2, "w", closefd=False, encoding="utf-8")
        try:
            sys.argv = ["roadtwin", *argv]
            try:
                cli.main()
                code = 0
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        finally:
            sys.stdout.flush(), sys.stderr.flush()
            sys.stdout, sys.stderr = py_out, py_err
            os.dup2(old_out, 1), os.dup2(old_err, 2)
            os.close(old_out), os.close(old_err)
            sys.argv = saved
            for k, v in saved_env.items():
                os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
        fo.seek(0), fe.seek(0)
        return code, fo.read().decode("utf-8", "replace"), fe.read().decode("utf-8", "replace")


def _digest(c: Corpus, case_dir: Path, skip: Path | None) -> dict[str, object]:
    """Content hashes of the case's own files; size and mtime of the shared corpus (a write
    changes the mtime) and of the shipped samples."""
    out: dict[str, object] = {}
    for root, deep in ((case_dir, True), (c.inputs, False), (c.composed, False), (STAGES, False)):
        for p in sorted(root.rglob("*")):
            if p.is_file() and not (skip and (p == skip or skip in p.parents)):
                st = p.stat()
                out[str(p)] = hashlib.sha1(p.read_bytes()).hexdigest() if deep else (st.st_size, st.st_mtime_ns)
    return out


def _snapshot(path: Path | None) -> dict[str, bytes] | None:
    if path is None or not path.exists():
        return None
    if path.is_file():
        return {"": path.read_bytes()}
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Corpus:
    return Corpus(tmp_path_factory.mktemp("hostile usd"))


def _prepare(c: Corpus, d: Path, case: Case) -> Case:
    """Make what a case's arguments name but the builders leave implicit."""
    argv = []
    for a in case.argv:
        if a.startswith("LIB:"):
            name = a[4:]
            if name == "badlib":
                _truncate(c.asset, _mkdir(d, "badlib") / "bad.usda", 0.4)
            else:
                _write(d, name, "not a folder")
            a = str(d / name)
        argv.append(a)
    case.argv = argv
    for a in argv:
        if "/blocker/" in a:
            blocker = Path(a.split("/blocker/")[0]) / "blocker"
            blocker.parent.mkdir(parents=True, exist_ok=True)
            blocker.write_text("a regular file where a folder is needed\n")
    if case.output is not None and case.output.name in ("out.txt",):
        case.output.write_text("an earlier file\n")
    if case.output is not None and case.output.name in ("outdir.glb", "taken.usda"):
        case.output.mkdir(parents=True, exist_ok=True)
        (case.output / "keep.txt").write_text("kept\n")
    return case


IDS = [(cmd, name) for cmd, cases in CASES.items() for name in cases]


@pytest.mark.parametrize("command,name", IDS, ids=[f"{c}-{n}" for c, n in IDS])
def test_hostile_input(corpus: Corpus, command: str, name: str) -> None:
    d = corpus.case_dir(f"{command}-{name}")
    case = _prepare(corpus, d, CASES[command][name](corpus, d))
    before_in = _digest(corpus, d, case.scratch or case.output)
    before_out = _snapshot(case.output)
    code, out, err = _run(case.argv, case.env)
    text = out + err
    assert "Traceback" not in text and "internal error" not in text, f"{case.argv}:\n{text}"
    assert code in case.codes, f"exit {code} for {case.argv}:\n{text}"
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1, f"stderr is not one line for {case.argv}:\n{err}"
        assert case.names in lines[0], f"{lines[0]!r} does not name {case.names!r}"
    elif command != "library" or "list" not in case.argv:
        assert not err.strip(), f"exit {code} with stderr:\n{err}"
    assert _digest(corpus, d, case.scratch or case.output) == before_in, f"{case.argv} changed an input"
    if code != 0:
        assert _snapshot(case.output) == before_out, f"{case.argv}: output {case.output} changed"
    if case.output is not None and case.output.parent.is_dir():
        litter = [p.name for p in case.output.parent.iterdir() if ".tmp-" in p.name or ".old-" in p.name]
        assert not litter, f"{case.argv} left {litter}"
    if name == "add-composed":
        assert code == 0 and (case.output / corpus.asset.name).is_file()
    if name.startswith("composed-") or name in ("composed-town", "list-composed", "show-composed", "out-with-spaces"):
        assert code == 0, text


def test_case_counts() -> None:
    """Every command has a corpus; the counts are in the closing note."""
    counts = {cmd: len(cases) for cmd, cases in CASES.items()}
    assert all(n >= 4 for n in counts.values()), counts
    assert sum(counts.values()) >= 80, counts


if __name__ == "__main__":
    for cmd, cases in CASES.items():
        print(f"{cmd}: {len(cases)} cases")
