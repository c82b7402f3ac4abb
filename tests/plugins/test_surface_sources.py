"""Elevation sources named on the command line: usd:SURFACE.usda (core) and crg:FILE (plugin)."""
from __future__ import annotations

import numpy as np
import pytest
import triangle
from pxr import Usd, UsdGeom

from roadtwin_core import ComposeRules, RoadSegment, RoadtwinError, TownLayout, parse_surface
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.usd import new_stage, write_layout
from roadtwin_core.usd.stage import write_mesh

CRG = "tests/data/opencrg/handmade_straight.crg"


def _plane_asset(path):
    """A reconstructed-surface-like asset: a tilted plane z = 0.1 x - 0.05 y + 2 on a 0.5 m grid."""
    gx, gy = np.meshgrid(np.arange(-2, 32, 0.5), np.arange(-2, 10, 0.5))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    tri = triangle.triangulate({"vertices": xy}, "")
    z = 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 2.0
    stage = new_stage(path, "Surface")
    UsdGeom.Xform.Define(stage, "/Surface")
    write_mesh(UsdGeom.Mesh.Define(stage, "/Surface/mesh"), np.column_stack([xy, z]), tri["triangles"])
    stage.GetRootLayer().Save()


def test_usd_surface_asset_reproduces_a_plane(tmp_path):
    _plane_asset(tmp_path / "s.usda")
    surf = parse_surface(f"usd:{tmp_path / 's.usda'}", (0, 0, 1, 1), 0)
    xy = np.random.default_rng(0).uniform([0, 0], [30, 8], (200, 2))
    assert np.allclose(surf.height(xy), 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 2.0, atol=1e-5)  # float32 points


def test_compose_on_a_surface_asset(tmp_path):
    _plane_asset(tmp_path / "s.usda")
    poly = np.array([[0, 0], [30, 0], [30, 7], [0, 7]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
    seg = RoadSegment("lane", "driving", t["vertices"], t["triangles"], np.array([[0, 3.5], [30, 3.5]]))
    write_layout(TownLayout("Town", [seg], ComposeRules(defect_count=0, surface="flat")), tmp_path / "road.usda")
    compose(tmp_path / "road.usda", tmp_path / "out", surface=f"usd:{tmp_path / 's.usda'}", preview=False)
    stage = Usd.Stage.Open(str(tmp_path / "out" / "town.usda"))
    pts = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/Town/Roads/lane")).GetPointsAttr().Get(), dtype=float)
    assert np.allclose(pts[:, 2], 0.1 * pts[:, 0] - 0.05 * pts[:, 1] + 2.0, atol=1e-4)


def test_crg_plugin_is_an_elevation_source():
    surf = parse_surface(f"crg:{CRG}", (0, 0, 1, 1), 0)
    assert type(surf).__name__ == "CrgSurface"
    assert np.isfinite(surf.height(np.array([[5.0, 0.0], [20.0, 1.0]]))).all()


def test_unknown_or_missing_sources_are_refused(tmp_path):
    with pytest.raises(RoadtwinError, match="unknown source 'nope:x'.*crg:ARG"):
        parse_surface("nope:x", (0, 0, 1, 1), 0)
    with pytest.raises(RoadtwinError, match="no such file"):
        parse_surface(f"usd:{tmp_path / 'missing.usda'}", (0, 0, 1, 1), 0)
