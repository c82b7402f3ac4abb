"""compose and the roadside world: ``props="none"`` writes no props layer (the stage is what it
was before props existed), a rules file places exactly its rules, and the built-in rules fit what
they can on a small layout without failing."""
from __future__ import annotations

import json

import numpy as np
import pytest
import triangle
from pxr import Sdf, Usd, UsdGeom

from roadtwin_core import ComposeRules, RoadSegment, TownLayout
from roadtwin_core.apps.compose.run import compose
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
