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


def wheel_path_town(pm, base, fixed: FixedDefect, shoulder: bool = True):
    """A straight two-lane road (x 0-40 m; right lane y -3.5..0, travel +x), with its shoulder, and
    the one pinned defect ``fixed``, composed into ``base/town``: its stage."""
    segs = []
    for i, x in enumerate(np.arange(0.0, 40.0, 20.0)):
        x1 = x + 20.0
        segs += [_strip(f"r{i}", "driving", x, x1, -LANE_W, 0.0, np.array([[x, -LANE_W / 2], [x1, -LANE_W / 2]])),
                 _strip(f"l{i}", "driving", x, x1, 0.0, LANE_W, np.array([[x1, LANE_W / 2], [x, LANE_W / 2]]))]
        if shoulder:
            segs.append(_strip(f"s{i}", "shoulder", x, x1, -LANE_W - 2.0, -LANE_W))
    rules = ComposeRules(defect_count=0, seed=1, surface="flat", models_per_type=1, type_weights={"pothole": 1.0})
    layout = TownLayout("Town", segs, rules)
    layout.fixed = [fixed]
    write_layout(layout, base / "road.usda")
    return compose(base / "road.usda", base / "town", preview=False, executor="serial", pm=pm).town


def survey_frame(town, pm, out, eye_x: float, size: str, defect_type: str):
    """One frame through the survey rig from (eye_x, the right lane's centre), looking along +x,
    with builtin:road_defects_br: (the defect's instance mask, semantic labels, grey image, the map)."""
    rig = RIG_PRESETS["survey"]
    out.mkdir(parents=True, exist_ok=True)
    poses = out / "poses.json"
    poses.write_text(json.dumps([{"cam_to_world": look_from((eye_x, -LANE_W / 2, rig.height_m), 0.0,
                                                            math.radians(rig.pitch_deg)).tolist()}]))
    frames = out / "r"
    run_render(town, frames, RenderOptions(rig="survey", size=size, frames=1, poses=poses, formats="mmseg,coco",
                                           executor="serial", classmap="builtin:road_defects_br"), pm=pm)
    meta = json.loads((frames / "meta.json").read_text())
    (fr,) = meta["frames"]
    (defect_id,) = [i["id"] for i in meta["instances"] if i["type"] == defect_type]
    labels = cv2.imread(str(frames / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
    inst = cv2.imread(str(frames / fr["files"]["instance"]), cv2.IMREAD_UNCHANGED)
    rgb = cv2.imread(str(frames / fr["files"]["rgb"]), cv2.IMREAD_GRAYSCALE).astype(float)
    return inst == defect_id, labels, rgb, load_class_map("road_defects_br")


@pytest.fixture(scope="module")
def town(pm, tmp_path_factory):
    """A straight two-lane road with one 6 m x 0.8 m ravelled strip in the right lane's right wheel path."""
    strip = FixedDefect("R0", "ravelling", {"length_m": 6.0, "width_m": 0.8, "depth_m": 0.02, "taper_m": 0.3,
                                            "wander_m": 0.0}, x=STRIP_X, y=-LANE_W / 2 - 0.85, seed=0)
    return wheel_path_town(pm, tmp_path_factory.mktemp("ravelling"), strip)


def test_ravelling_composes_validates_and_is_a_road_defect(town):
    assert not [f for f in validate_stage(town) if f.severity == "Error"]
    stage = Usd.Stage.Open(str(town))
    (prim,) = stage.GetPrimAtPath("/Town/Defects").GetChildren()
    assert prim.GetAttribute("roadtwin:defect:type").Get() == "ravelling"
    assert list(UsdSemantics.LabelsAPI(prim, "class").GetLabelsAttr().Get()) == ["road_defect", "ravelling"]


def test_ravelling_pixels_are_pothole_under_road_defects_br_and_darker_than_the_lane(town, pm, tmp_path):
    sel, labels, rgb, cmap = survey_frame(town, pm, tmp_path, STRIP_X - 3.0 - 8.0, "256x160", "ravelling")
    assert sel.sum() > 200                                           # the strip fills part of the view
    assert (labels[sel] == cmap.classes.index("pothole")).mean() > 0.95
    lane = (labels == cmap.classes.index("ego_lane")) & ~sel
    assert np.median(rgb[sel]) < 0.85 * np.median(rgb[lane])           # exposed aggregate: darker than the lane
