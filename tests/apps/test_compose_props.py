"""compose and the roadside world: ``props="none"`` writes no props layer (the stage is what it
was before props existed), a rules file places exactly its rules, and the built-in rules fit what
they can on a small layout without failing. The terrain never comes up inside the paved surface
(a pothole deeper than its 8 cm would show it) yet meets the road edge without a gap."""
from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
import triangle
from pxr import Sdf, Usd, UsdGeom
from shapely.geometry import Point, box
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from roadtwin_core import ComposeRules, RoadSegment, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.town.terrain import terrain_mesh
from roadtwin_core.usd import write_layout


@pytest.fixture(scope="module")
def layout(tmp_path_factory):
    """A 60 m x 7 m two-lane road with 2 m verges."""
    tmp = tmp_path_factory.mktemp("props_layout")

    def seg(name, kind, y0, y1, centerline=None):
        poly = np.array([[0, y0], [60, y0], [60, y1], [0, y1]], dtype=float)
        t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
        return RoadSegment(name, kind, t["vertices"], t["triangles"], centerline)

    segments = [seg("east", "driving", 0, 3.5, np.array([[0, 1.75], [60, 1.75]])),
                seg("west", "driving", 3.5, 7, np.array([[60, 5.25], [0, 5.25]])),
                seg("verge_s", "verge", -2, 0), seg("verge_n", "verge", 7, 9)]
    path = tmp / "road.usda"
    write_layout(TownLayout("Town", segments, ComposeRules(defect_count=4, seed=2, surface="flat",
                                                          type_weights={"pothole": 1.0}, models_per_type=1)), path)
    return path


def _sublayers(out) -> list[str]:
    layer = Sdf.Layer.OpenAsAnonymous(str(out / "town.usda"))
    return list(layer.subLayerPaths)


def test_props_none_writes_no_props_layer(layout, tmp_path):
    out = tmp_path / "none"
    compose(layout, out, preview=False, executor="serial", props="none")
    assert not (out / "layers" / "props.usda").exists() and not (out / "layers" / "props.geom.usdc").exists()
    assert "./layers/props.usda" not in _sublayers(out)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["props"] == {"instances": 0, "by_rule": {}}


def test_rules_file_places_exactly_its_rules(layout, tmp_path):
    rules = tmp_path / "rules.toml"
    rules.write_text('[[rule]]\nname = "row"\ngroup = "Row"\nprototypes = {tree_conifer = 1}\n'
                     'offset_m = [3, 3]\nspacing_m = 6\ndensity_per_km = 1000\nscale = [1, 1]\n')
    out = tmp_path / "rules"
    compose(layout, out, preview=False, executor="serial", props=rules)
    stage = Usd.Stage.Open(str(out / "town.usda"))
    groups = [p.GetName() for p in stage.GetPrimAtPath("/Town/Props").GetChildren() if p.IsA(UsdGeom.PointInstancer)]
    assert groups == ["Row"]
    pos = np.asarray(UsdGeom.PointInstancer(stage.GetPrimAtPath("/Town/Props/Row")).GetPositionsAttr().Get())
    # 3 m out from the paved edge (the verges are not paved): y = -3 or y = 10, or beyond the road's ends
    assert len(pos) >= 10 and ((pos[:, 1] < -2.5) | (pos[:, 1] > 9.5) | (pos[:, 0] < -2.5) | (pos[:, 0] > 62.5)).all()
    assert json.loads((out / "summary.json").read_text())["props"]["by_rule"] == {"row": len(pos)}
    assert "./layers/props.usda" in _sublayers(out)


def test_default_rules_fit_what_they_can(layout, tmp_path):
    out = tmp_path / "default"
    compose(layout, out, preview=False, executor="serial")
    by_rule = json.loads((out / "summary.json").read_text())["props"]["by_rule"]
    assert {"trees", "shrubs", "tall_grass", "hills"} <= set(by_rule)


def test_prototypes_carry_outward_flat_normals(layout, tmp_path):
    """Other tools shade the props as roadtwin draws them: every prototype part has one unit
    normal per face corner (faceVarying), constant over each face, and pointing away from the
    part's centre for nearly every face (closed faceted shapes, wound outwards)."""
    out = tmp_path / "normals"
    compose(layout, out, preview=False, executor="serial")
    stage = Usd.Stage.Open(str(out / "town.usda"))
    parts = [UsdGeom.Mesh(p) for p in Usd.PrimRange(stage.GetPrimAtPath("/Town/Props"))
             if p.IsA(UsdGeom.Mesh) and "/Prototypes/" in str(p.GetPath())]
    assert len(parts) >= 5
    for mesh in parts:
        pts = np.asarray(mesh.GetPointsAttr().Get(), float)
        tris = np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        normals = np.asarray(mesh.GetNormalsAttr().Get(), float).reshape(-1, 3, 3)
        assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.faceVarying and len(normals) == len(tris)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=2), 1.0, atol=1e-5)
        np.testing.assert_allclose(normals[:, 0], normals[:, 2], atol=1e-6)
        # each closed piece's own centre (a part may hold several: a car's four wheels)
        n = len(pts)
        graph = coo_matrix((np.ones(2 * tris.size), (np.r_[tris.ravel(), np.roll(tris, 1, 1).ravel()],
                                                     np.r_[np.roll(tris, 1, 1).ravel(), tris.ravel()])), shape=(n, n))
        _, piece = connected_components(graph, directed=False)
        centre = np.array([pts[piece == k].mean(axis=0) for k in range(piece.max() + 1)])[piece[tris[:, 0]]]
        away = ((pts[tris].mean(axis=1) - centre) * normals[:, 0]).sum(axis=1)
        assert (away > 0).mean() >= 0.9, (mesh.GetPath(), (away > 0).mean())


def _terrain_cover(v, f):
    return shapely.union_all(shapely.polygons(np.asarray(v, float)[np.asarray(f).reshape(-1, 3)][:, :, :2]))


def test_terrain_stays_out_of_the_road_and_meets_its_edge(layout, tmp_path):
    """The road is the box 0..60 x 0..7 (the verges are not paved): no terrain 0.5 m or more in
    from its edge, the 0.5 m band under the edge and everything around the road covered, every
    terrain vertex 8 cm under the flat road (z = 0)."""
    out = tmp_path / "terrain"
    compose(layout, out, preview=False, executor="serial")
    stage = Usd.Stage.Open(str(out / "town.usda"))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Town/Props/Terrain"))
    v = np.asarray(mesh.GetPointsAttr().Get(), float)
    cover = _terrain_cover(v, mesh.GetFaceVertexIndicesAttr().Get())
    road, inner = box(0, 0, 60, 7), box(0.5, 0.5, 59.5, 6.5)
    assert cover.intersection(inner).area < 1e-6, cover.intersection(inner).area
    around = box(-30, -30, 90, 37).difference(road)
    assert cover.intersection(around).area == pytest.approx(around.area, rel=1e-9)
    assert cover.intersection(road.difference(inner)).area >= 0.9 * (road.area - inner.area)
    np.testing.assert_allclose(v[:, 2], -0.08, atol=1e-6)


def test_terrain_is_cut_under_a_defect_at_the_road_edge():
    """A defect's disc on the paved edge: no terrain under its paved part, terrain beyond the edge."""
    road, disc = box(0, 0, 60, 7), Point(20, 0.2).buffer(0.6, quad_segs=64)
    v, f = terrain_mesh(road, lambda xy: np.full(len(xy), 1.5), np.array([[20, 0.2, 0.6]]))
    cover = _terrain_cover(v, f)
    assert cover.intersection(disc.intersection(road)).area < 1e-6
    assert cover.intersection(disc.difference(road)).area == pytest.approx(disc.difference(road).area, rel=1e-9)
    assert cover.intersection(box(0.5, 0.5, 59.5, 6.5)).area < 1e-6
    np.testing.assert_allclose(v[:, 2], 1.42)
