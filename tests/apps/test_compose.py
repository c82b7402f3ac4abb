"""End to end: compose the sample town through the real CLI, then check the result with pxr alone.

Nothing here trusts roadtwin's own readers or summary: the stage is reopened with pxr, validated
with ``pxr.UsdValidation``, labels are resolved with ``UsdSemantics.LabelsQuery``, areas come from
the input layout file's planar mesh, depths from the road vertices around each defect.

Three composes run once per module, concurrently (they are separate processes): A (the one most
tests read), B (same arguments as A: must be byte-identical) and C (another seed).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Kind, Sdf, Usd, UsdGeom, UsdPhysics, UsdSemantics, UsdShade, UsdValidation

REPO = Path(__file__).resolve().parents[2]
TOWN = REPO / "stages" / "town.usda"
N_DEFECTS = 12
SEED = 7
# Sublayers of town.usda, strongest first (docs/architecture.md#layers-of-a-town-stage).
LAYER_ORDER = ["looks", "semantics", "physics", "props", "markings", "defects", "roads", "layout"]
# The roadside world's class labels (layers/props.usda, on by default).
PROP_LABELS = {"vegetation", "pole", "sign", "vehicle", "terrain", "guardrail", "fence"}
DEPRESSION_TYPES = {"pothole", "depression", "rut", "crack"}
ROOT = "/Town"


def cli(*args: str) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    return subprocess.Popen([sys.executable, "-m", "roadtwin_core.cli", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen, timeout: float = 240) -> None:
    out, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, f"compose failed ({proc.returncode}):\n{err}\n{out}"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("compose")
    outs = {k: base / k for k in "ABC"}
    common = [str(TOWN), "--defects", str(N_DEFECTS)]
    procs = [cli("compose", *common, "--seed", str(SEED), "-o", str(outs["A"])),
             cli("compose", *common, "--seed", str(SEED), "-o", str(outs["B"]), "--no-preview"),
             cli("compose", *common, "--seed", str(SEED + 1), "-o", str(outs["C"]), "--no-preview")]
    for p in procs:
        finish(p)
    return outs


@pytest.fixture(scope="module")
def out(runs) -> Path:
    return runs["A"]


@pytest.fixture(scope="module")
def stage(out) -> Usd.Stage:
    s = Usd.Stage.Open(str(out / "town.usda"))
    assert s, "town.usda does not open"
    return s


@pytest.fixture(scope="module")
def layout_meshes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The input layout's segment meshes, read straight from stages/town.usda: name -> (points, tris)."""
    s = Usd.Stage.Open(str(TOWN))
    meshes = {}
    for prim in s.Traverse():
        if prim.IsA(UsdGeom.Mesh) and prim.HasAttribute("roadtwin:segment:kind"):
            meshes[prim.GetName()] = mesh_arrays(prim)
    assert meshes
    return meshes


def mesh_arrays(prim: Usd.Prim) -> tuple[np.ndarray, np.ndarray]:
    m = UsdGeom.Mesh(prim)
    pts = np.asarray(m.GetPointsAttr().Get(), dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(m.GetFaceVertexCountsAttr().Get())
    idx = np.asarray(m.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
    assert (counts == 3).all(), f"{prim.GetPath()}: not a triangle mesh"
    return pts, idx.reshape(-1, 3)


def signed_areas(pts: np.ndarray, tris: np.ndarray) -> np.ndarray:
    a, b, c = (pts[tris[:, i], :2] for i in range(3))
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def defect_prims(stage: Usd.Stage) -> list[Usd.Prim]:
    group = stage.GetPrimAtPath(f"{ROOT}/Defects")
    assert group
    return list(group.GetChildren())


# --------------------------------------------------------------------------- outputs
def test_files_and_summary(out):
    png = out / "preview.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["defects"] == N_DEFECTS
    assert summary["seed"] == SEED
    assert summary["validation"]["errors"] == 0
    looks = Usd.Stage.Open(str(out / "layers" / "looks.usda"))
    assert summary["materials"] == sum(p.IsA(UsdShade.Material) for p in looks.Traverse()) > 0
    marks = Usd.Stage.Open(str(out / "layers" / "markings.usda"))
    assert summary["markings"] == sum(p.IsA(UsdGeom.Mesh) for p in marks.Traverse())
    for key in ("place_s", "merge_s", "write_s"):
        assert summary["timings_s"][key] >= 0
    # The input layout is copied untouched.
    assert (out / "layout" / TOWN.name).read_bytes() == TOWN.read_bytes()
    # No temporary directories left beside the output.
    assert sorted(p.name for p in out.parent.iterdir()) == ["A", "B", "C"]


def test_usd_validation_has_no_errors(stage):
    registry = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    errors = [e for e in ctx.Validate(stage)
              if not e.HasNoError() and e.GetType() == UsdValidation.ValidationErrorType.Error]
    assert not errors, "\n".join(f"{e.GetValidator().GetMetadata().name if e.GetValidator() else ''}: "
                                 f"{e.GetMessage()}" for e in errors[:10])


def layer_files(out: Path) -> list[Path]:
    return [out / "town.usda", *sorted((out / "layers").glob("*.usd[ac]")), *sorted((out / "library").glob("*.usda"))]


def test_every_layer_has_stage_metadata(out):
    files = layer_files(out)
    assert {p.stem for p in (out / "layers").glob("*.usda")} == set(LAYER_ORDER[:-1])
    # Heavy arrays live in crate files beside the layers that sublayer them
    # (docs/architecture.md#geometry-in-crate-sublayers).
    assert {p.name for p in (out / "layers").glob("*.usdc")} == {f"{n}.geom.usdc"
                                                                 for n in ("roads", "defects", "markings", "props")}
    assert len(list((out / "library").glob("*.usda"))) > 0
    for path in files:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))  # a fresh read of the file, no registry cache
        assert layer, path
        info = layer.pseudoRoot
        assert info.GetInfo("upAxis") == "Z", path
        assert info.GetInfo("metersPerUnit") == 1.0, path
        assert info.GetInfo("kilogramsPerUnit") == 1.0, path
        assert layer.defaultPrim, path
        assert layer.GetPrimAtPath(Sdf.Path.absoluteRootPath.AppendChild(layer.defaultPrim)), path
        s = Usd.Stage.Open(str(path), Usd.Stage.LoadNone)
        assert UsdGeom.GetStageUpAxis(s) == UsdGeom.Tokens.z, path
        assert s.HasAuthoredMetadata("metersPerUnit") and UsdGeom.GetStageMetersPerUnit(s) == 1.0, path
        assert s.HasAuthoredMetadata("kilogramsPerUnit") and UsdPhysics.GetStageKilogramsPerUnit(s) == 1.0, path
        assert s.GetDefaultPrim(), path


def test_sublayer_order(out):
    layer = Sdf.Layer.OpenAsAnonymous(str(out / "town.usda"))
    subs = list(layer.subLayerPaths)
    assert len(subs) == len(LAYER_ORDER)
    resolved = [(out / p).resolve() for p in subs]
    assert resolved[:-1] == [(out / "layers" / f"{n}.usda").resolve() for n in LAYER_ORDER[:-1]]
    assert resolved[-1] == (out / "layout" / TOWN.name).resolve()
    assert all(p.is_file() for p in resolved)


# --------------------------------------------------------------------------- semantics and kinds
def test_renderable_meshes_have_road_labels(stage):
    query = UsdSemantics.LabelsQuery("class", Usd.TimeCode.Default())
    n = 0
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or UsdGeom.Imageable(prim).ComputePurpose() == UsdGeom.Tokens.guide:
            continue
        labels = set(query.ComputeUniqueInheritedLabels(prim))
        if str(prim.GetPath()).startswith(f"{ROOT}/Props/"):     # the roadside world: its own labels
            assert labels & PROP_LABELS, f"{prim.GetPath()}: labels {sorted(labels)}"
            continue
        assert labels & {"road", "road_defect", "lane_marking"}, f"{prim.GetPath()}: labels {sorted(labels)}"
        n += 1
    assert n > N_DEFECTS


def test_defects_labelled_with_their_type(stage):
    query = UsdSemantics.LabelsQuery("class", Usd.TimeCode.Default())
    for prim in defect_prims(stage):
        dtype = prim.GetAttribute("roadtwin:defect:type").Get()
        meshes = [c for c in prim.GetChildren() if c.IsA(UsdGeom.Mesh)]
        assert meshes, f"{prim.GetPath()}: no baked mesh"
        for m in meshes:
            assert {"road_defect", dtype} <= set(query.ComputeUniqueInheritedLabels(m)), m.GetPath()


def test_kinds(stage, layout_meshes):
    def kind(path):
        prim = stage.GetPrimAtPath(path)
        assert prim, path
        return Usd.ModelAPI(prim).GetKind()

    assert kind(ROOT) == Kind.Tokens.assembly
    assert kind(f"{ROOT}/Roads") == Kind.Tokens.group
    assert kind(f"{ROOT}/Defects") == Kind.Tokens.group
    for name in layout_meshes:
        assert kind(f"{ROOT}/Roads/{name}") == Kind.Tokens.component, name
    for prim in defect_prims(stage):
        assert Usd.ModelAPI(prim).GetKind() == Kind.Tokens.component, prim.GetPath()
        assert prim.IsModel()


# --------------------------------------------------------------------------- defects
def test_defect_count_and_attributes(stage):
    prims = defect_prims(stage)
    assert len(prims) == N_DEFECTS
    for prim in prims:
        values = {}
        for key in ("type", "depthM", "areaM2", "volumeM3"):
            attr = prim.GetAttribute(f"roadtwin:defect:{key}")
            assert attr and attr.HasAuthoredValue(), f"{prim.GetPath()}: no roadtwin:defect:{key}"
            values[key] = attr.Get()
        assert isinstance(values["type"], str) and values["type"]
        for key in ("depthM", "areaM2", "volumeM3"):
            assert math.isfinite(values[key]) and values[key] >= 0, (prim.GetPath(), key, values[key])
        assert values["areaM2"] > 0, prim.GetPath()
        if values["type"] in DEPRESSION_TYPES:
            assert values["depthM"] > 0, prim.GetPath()
            assert values["volumeM3"] > 0, prim.GetPath()


def _fit_quadric(xy: np.ndarray, z: np.ndarray):
    """Least-squares z = quadric(x, y) (centred for conditioning); returns an evaluator."""
    c = xy.mean(axis=0)

    def basis(q):
        q = q - c
        return np.column_stack([np.ones(len(q)), q[:, 0], q[:, 1], q[:, 0] ** 2, q[:, 0] * q[:, 1], q[:, 1] ** 2])

    coef = np.linalg.lstsq(basis(xy), z, rcond=None)[0]
    return lambda q: basis(q) @ coef


def test_defect_depth_below_surrounding_road(stage):
    """The deepest point of each baked defect lies depthM below the road around it (and its highest
    point heightM above it), on the rough, tilted sample surface.

    The road under a defect is estimated as a quadric fitted to the road vertices (roads layer:
    road faces only, so the seam but no defect interior) within 0.6 m of the defect's bounding
    box. That removes the terrain tilt and curvature but not the ISO 8608 roughness under the
    footprint, so the tolerance is 2 mm plus three times the fit's residual on the road itself
    (about 1 mm here; long ruts see the most roughness)."""
    road = [mesh_arrays(p)[0] for p in stage.GetPrimAtPath(f"{ROOT}/Roads").GetChildren() if p.IsA(UsdGeom.Mesh)]
    road_pts = np.concatenate(road)
    checked = 0
    for prim in defect_prims(stage):
        pts = np.concatenate([mesh_arrays(m)[0] for m in prim.GetChildren() if m.IsA(UsdGeom.Mesh)])
        lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        near = road_pts[((road_pts[:, :2] > lo - 0.6) & (road_pts[:, :2] < hi + 0.6)).all(axis=1)]
        assert len(near) >= 20, f"{prim.GetPath()}: too few road vertices around it"
        surface = _fit_quadric(near[:, :2], near[:, 2])
        sigma = float((near[:, 2] - surface(near[:, :2])).std())
        assert sigma < 0.003, f"{prim.GetPath()}: road around it is not smooth ({sigma * 1e3:.1f} mm rms)"
        tol = 0.002 + 3 * sigma
        rel = pts[:, 2] - surface(pts[:, :2])
        depth = prim.GetAttribute("roadtwin:defect:depthM").Get()
        height = prim.GetAttribute("roadtwin:defect:heightM").Get()
        assert abs(max(0.0, -rel.min()) - depth) < tol, (prim.GetPath(), -rel.min(), depth, tol)
        assert abs(max(0.0, rel.max()) - height) < tol, (prim.GetPath(), rel.max(), height, tol)
        checked += 1
    assert checked == N_DEFECTS


# --------------------------------------------------------------------------- physics
def colliders(stage: Usd.Stage) -> list[Usd.Prim]:
    return [p for p in stage.Traverse() if p.HasAPI(UsdPhysics.CollisionAPI)]


def test_colliders_are_the_rendered_road_and_defect_meshes(stage, layout_meshes):
    """The physics layer marks the road and defect meshes themselves
    (docs/architecture.md#physics-on-the-same-meshes: no copies)."""
    found = colliders(stage)
    roads = {p.GetName() for p in found if str(p.GetParent().GetPath()) == f"{ROOT}/Roads"}
    pieces = [p for p in found if str(p.GetPath()).startswith(f"{ROOT}/Defects/")]
    assert roads == set(layout_meshes)
    assert len(roads) + len(pieces) == len(found)
    want_pieces = [p for d in defect_prims(stage) for p in d.GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert sorted(map(str, (p.GetPath() for p in pieces))) == sorted(map(str, (p.GetPath() for p in want_pieces)))
    for prim in found:
        assert prim.IsA(UsdGeom.Mesh), prim.GetPath()
        assert prim.HasAPI(UsdPhysics.MeshCollisionAPI), prim.GetPath()
        assert UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get() == UsdPhysics.Tokens.none
        assert not prim.HasAPI(UsdPhysics.RigidBodyAPI), f"{prim.GetPath()}: colliders are static"
        assert UsdGeom.Imageable(prim).ComputePurpose() == UsdGeom.Tokens.default_, prim.GetPath()


def test_collision_area_matches_layout(stage, layout_meshes):
    """Per segment, the colliders (road mesh + the defect pieces cut into it) cover the layout's area."""
    found = colliders(stage)
    for name, (lpts, ltris) in layout_meshes.items():
        want = abs(float(signed_areas(lpts, ltris).sum()))
        assert want > 0
        a = np.concatenate([signed_areas(*mesh_arrays(p)) for p in found if p.GetName() == name])
        # One orientation throughout (no folded-over triangles), and the same outline area.
        assert (a > 0).all() or (a < 0).all(), name
        got = abs(float(a.sum()))
        assert abs(got - want) <= 1e-6 * want, (name, got, want)


# --------------------------------------------------------------------------- layers
def test_muting_roads_restores_planar_layout(out, layout_meshes):
    s = Usd.Stage.Open(str(out / "town.usda"))
    roads_layer = Sdf.Layer.FindOrOpen(str(out / "layers" / "roads.usda"))
    probe = next(iter(layout_meshes))
    merged_pts = mesh_arrays(s.GetPrimAtPath(f"{ROOT}/Roads/{probe}"))[0]
    assert np.abs(merged_pts[:, 2]).max() > 0, "the merged road should carry elevation"
    s.MuteLayer(roads_layer.identifier)
    assert s.IsLayerMuted(roads_layer.identifier)
    for name, (lpts, ltris) in layout_meshes.items():
        pts, tris = mesh_arrays(s.GetPrimAtPath(f"{ROOT}/Roads/{name}"))
        assert np.array_equal(pts, lpts), name
        assert np.array_equal(tris, ltris), name
        assert (pts[:, 2] == 0).all(), name


def test_props_are_instanced_and_muting_removes_exactly_them(out, stage):
    """layers/props.usda: PointInstancers (each prototype stored once), a terrain mesh, labelled;
    small beside the town (< 10 % of its USD bytes); no collider; muting it removes /Town/Props
    and changes no other prim."""
    summary = json.loads((out / "summary.json").read_text())
    instancers = [p for p in Usd.PrimRange(stage.GetPrimAtPath(f"{ROOT}/Props")) if p.IsA(UsdGeom.PointInstancer)]
    n = sum(len(UsdGeom.PointInstancer(p).GetProtoIndicesAttr().Get()) for p in instancers)
    assert n == summary["props"]["instances"] == sum(summary["props"]["by_rule"].values()) > 300
    meshes = [p for p in Usd.PrimRange(stage.GetPrimAtPath(f"{ROOT}/Props")) if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) < 80 and stage.GetPrimAtPath(f"{ROOT}/Props/Terrain").IsA(UsdGeom.Mesh)
    assert not any(p.HasAPI(UsdPhysics.CollisionAPI) for p in meshes)
    usd = [p for p in (out / "layers").glob("*.usd[ac]")] + [out / "town.usda"]
    props_bytes = sum(p.stat().st_size for p in usd if p.name.startswith("props."))
    assert props_bytes < 0.1 * sum(p.stat().st_size for p in usd)
    before = {str(p.GetPath()) for p in stage.Traverse()}
    s = Usd.Stage.Open(str(out / "town.usda"))
    s.MuteLayer(Sdf.Layer.FindOrOpen(str(out / "layers" / "props.usda")).identifier)
    after = {str(p.GetPath()) for p in s.Traverse()}
    assert after == {p for p in before if not p.startswith(f"{ROOT}/Props")}


# --------------------------------------------------------------------------- determinism
def stage_files(out: Path) -> dict[str, bytes]:
    files = [out / "town.usda", *(out / "layers").glob("*.usd[ac]"), *(out / "library").glob("*.usda"),
             *(out / "layout").glob("*"), *(out / "textures").glob("*")]
    return {str(p.relative_to(out)): p.read_bytes() for p in files}


def test_same_seed_same_bytes(runs):
    a, b = stage_files(runs["A"]), stage_files(runs["B"])
    assert sorted(a) == sorted(b)
    assert len(a) > 6
    differ = [k for k in a if a[k] != b[k]]
    assert not differ, f"not byte-identical: {differ}"


def test_other_seed_other_defects(runs):
    a = (runs["A"] / "layers" / "defects.usda").read_bytes()
    c = (runs["C"] / "layers" / "defects.usda").read_bytes()
    assert a != c
    assert json.loads((runs["C"] / "summary.json").read_text())["defects"] == N_DEFECTS
