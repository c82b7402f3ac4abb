"""Ravelling (plugins/roadtwin_defects/ravelling.py): a wheel-path strip that composes into a
town that validates, is labelled a road defect in the stage, and renders as pothole under
builtin:road_defects_br (whose annotators labelled such strips pothole), darker than its lane."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import triangle
from pxr import Usd, UsdSemantics

import roadtwin_cdt
import roadtwin_defects
import roadtwin_warp_render
from roadtwin_core import ComposeRules, FixedDefect, PluginManager, RoadSegment, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.apps.render import RenderOptions, run_render
from roadtwin_core.render.cameras import RIG_PRESETS, look_from
from roadtwin_core.render.classmap import load_class_map
from roadtwin_core.usd import validate_stage, write_layout

LANE_W = 3.5
STRIP_X = 14.0          # the strip's centre along the road; the camera stands 8 m behind its start


def _strip(name, kind, x0, x1, y0, y1, centerline=None) -> RoadSegment:
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "pqa4")
    return RoadSegment(name, kind, t["vertices"], t["triangles"], centerline)


@pytest.fixture(scope="module")
def pm():
    m = PluginManager(load_entry_points=False)
    for mod, name in ((roadtwin_cdt, "cdt"), (roadtwin_defects, "defects"), (roadtwin_warp_render, "warp_render")):
        m.register(mod, name=name)
    return m


@pytest.fixture(scope="module")
def town(pm, tmp_path_factory):
    """A straight two-lane road with one 6 m x 0.8 m ravelled strip in the right lane's right wheel path."""
    segs = []
    for i, x in enumerate(np.arange(0.0, 40.0, 20.0)):
        x1 = x + 20.0
        segs += [_strip(f"r{i}", "driving", x, x1, -LANE_W, 0.0, np.array([[x, -LANE_W / 2], [x1, -LANE_W / 2]])),
                 _strip(f"l{i}", "driving", x, x1, 0.0, LANE_W, np.array([[x1, LANE_W / 2], [x, LANE_W / 2]])),
                 _strip(f"s{i}", "shoulder", x, x1, -LANE_W - 2.0, -LANE_W)]
    rules = ComposeRules(defect_count=0, seed=1, surface="flat", models_per_type=1, type_weights={"pothole": 1.0})
    layout = TownLayout("Town", segs, rules)
    layout.fixed = [FixedDefect("R0", "ravelling", {"length_m": 6.0, "width_m": 0.8, "depth_m": 0.02, "taper_m": 0.3,
                                                    "wander_m": 0.0}, x=STRIP_X, y=-LANE_W / 2 - 0.85, seed=0)]
    base = tmp_path_factory.mktemp("ravelling")
    write_layout(layout, base / "road.usda")
    return compose(base / "road.usda", base / "town", preview=False, executor="serial", pm=pm).town


def test_ravelling_composes_validates_and_is_a_road_defect(town):
    assert not [f for f in validate_stage(town) if f.severity == "Error"]
    stage = Usd.Stage.Open(str(town))
    (prim,) = stage.GetPrimAtPath("/Town/Defects").GetChildren()
    assert prim.GetAttribute("roadtwin:defect:type").Get() == "ravelling"
    assert list(UsdSemantics.LabelsAPI(prim, "class").GetLabelsAttr().Get()) == ["road_defect", "ravelling"]


def test_ravelling_pixels_are_pothole_under_road_defects_br_and_darker_than_the_lane(town, pm, tmp_path):
    rig = RIG_PRESETS["survey"]
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps([{"cam_to_world": look_from((STRIP_X - 3.0 - 8.0, -LANE_W / 2, rig.height_m), 0.0,
                                                            math.radians(rig.pitch_deg)).tolist()}]))
    out = tmp_path / "r"
    run_render(town, out, RenderOptions(rig="survey", size="256x160", frames=1, poses=poses, formats="mmseg,coco",
                                        executor="serial", classmap="builtin:road_defects_br"), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    (fr,) = meta["frames"]
    (strip_id,) = [i["id"] for i in meta["instances"] if i["type"] == "ravelling"]
    labels = cv2.imread(str(out / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
    inst = cv2.imread(str(out / fr["files"]["instance"]), cv2.IMREAD_UNCHANGED)
    rgb = cv2.imread(str(out / fr["files"]["rgb"]), cv2.IMREAD_GRAYSCALE).astype(float)
    cmap = load_class_map("road_defects_br")
    sel = inst == strip_id
    assert sel.sum() > 200                                           # the strip fills part of the view
    assert (labels[sel] == cmap.classes.index("pothole")).mean() > 0.95
    lane = (labels == cmap.classes.index("ego_lane")) & ~sel
    assert np.median(rgb[sel]) < 0.85 * np.median(rgb[lane])           # exposed aggregate: darker than the lane
