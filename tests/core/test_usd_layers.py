"""The composed stage's layers hold each mesh once: heavy arrays in crate files, collision on the
rendered meshes themselves (no copies, binary geometry: docs/architecture.md#usd-conventions).

The references are pxr alone: the layer files are opened as bare ``Sdf`` layers (what each file
itself authors), the rendered geometry is walked with ``UsdGeom`` on the composed stage.
"""
from __future__ import annotations

import numpy as np
import pytest
import triangle
from pxr import Sdf, Usd, UsdGeom, UsdPhysics

from roadtwin_core import ComposeRules, RoadSegment, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.usd import write_layout
from roadtwin_core.usd.town_reader import load_town

HEAVY = ("points", "faceVertexIndices", "faceVertexCounts", "primvars:st", "normals")


def _strip(x0: float, x1: float, y0: float, y1: float, name: str) -> RoadSegment:
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "pqa0.5")
    return RoadSegment(name, "driving", t["vertices"], t["triangles"], np.array([[x0, (y0 + y1) / 2], [x1, (y0 + y1) / 2]]))


@pytest.fixture(scope="module")
def town(tmp_path_factory):
    segs = [_strip(x, x + 12, y, y + 3.5, f"s{i}_{j}") for i, x in enumerate((0.0, 12.0)) for j, y in enumerate((0.0, 3.5))]
    rules = ComposeRules(defect_count=10, seed=5, surface="iso8608:C:0.1", models_per_type=2)
    base = tmp_path_factory.mktemp("layers")
    write_layout(TownLayout("Town", segs, rules), base / "strips.usda")
    return compose(base / "strips.usda", base / "out", preview=False, executor="serial").town


def _authored(path) -> dict[str, set[str]]:
    """Heavy attribute name -> prim paths that this one layer file authors a value for."""
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    found: dict[str, set[str]] = {name: set() for name in HEAVY}

    def visit(p: Sdf.Path) -> None:
        if p.IsPropertyPath() and p.name in found:
            spec = layer.GetAttributeAtPath(p)
            if spec is not None and spec.HasDefaultValue():
                found[p.name].add(str(p.GetPrimPath()))
    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found


def _world_triangles(mesh: UsdGeom.Mesh) -> np.ndarray:
    pts = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
    m = np.asarray(mesh.ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
    pts = pts @ m[:3, :3] + m[3, :3]
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    assert (counts == 3).all()
    return pts[np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)]


def _sorted_rows(tris: np.ndarray) -> np.ndarray:
    flat = tris.reshape(len(tris), 9)
    return flat[np.lexsort(flat.T[::-1])]


def test_no_array_is_authored_twice_and_none_in_text(town):
    out = town.parent
    files = sorted((out / "layers").glob("*.usd[ac]")) + [town]
    seen: dict[tuple[str, str], str] = {}
    points = 0
    for path in files:
        for name, prims in _authored(path).items():
            if prims:
                assert path.suffix == ".usdc", f"{path.name} authors {name} on {sorted(prims)[0]} in text"
            for prim in prims:
                assert (name, prim) not in seen, f"{name} of {prim} authored in {seen[name, prim]} and {path.name}"
                seen[name, prim] = path.name
            points += len(prims) if name == "points" else 0
    assert points > 10  # roads, defect pieces, markings
    assert not any(_authored(out / "layers" / "physics.usda").values())


def test_physics_collides_with_exactly_the_rendered_geometry(town):
    """What a physics backend reads (prims with CollisionAPI) is the rendered road: same prims,
    the same triangles in world space, nothing left over on either side."""
    stage = Usd.Stage.Open(str(town))
    colliders = [p for p in stage.Traverse() if p.HasAPI(UsdPhysics.CollisionAPI)]
    rendered = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)
                and UsdGeom.Imageable(p).ComputePurpose() in (UsdGeom.Tokens.default_, UsdGeom.Tokens.render)
                and ("/Roads/" in str(p.GetPath()) or "/Defects/" in str(p.GetPath()))]
    assert len(rendered) > 4
    assert {p.GetPath() for p in colliders} == {p.GetPath() for p in rendered}
    for prim in colliders:
        assert UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get() == UsdPhysics.Tokens.none
    want = _sorted_rows(np.concatenate([_world_triangles(UsdGeom.Mesh(p)) for p in rendered]))
    # roadtwin's physics input (load_town().collision_mesh(), what sweep and the CRG export read).
    verts, faces = load_town(town).collision_mesh()
    got = _sorted_rows(verts[faces])
    assert got.shape == want.shape
    assert np.array_equal(got, want)


def test_muting_the_physics_layer_removes_collision_only(town):
    stage = Usd.Stage.Open(str(town))
    before = {str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)}
    stage.MuteLayer(Sdf.Layer.FindOrOpen(str(town.parent / "layers" / "physics.usda")).identifier)
    assert not [p for p in stage.Traverse() if p.HasAPI(UsdPhysics.CollisionAPI)]
    assert {str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)} == before
