"""Alligator cracking (plugins/roadtwin_defects/alligator.py): a wheel-path area of small crack
cells, one simple polygon (the DefectModel contract), with as much crack per square metre as a
hexagonal tiling of its cell size has (a closed form), labelled crack under road_defects_br."""
from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import pytest

from roadtwin_core import ComposeRules, FixedDefect, PluginManager, RoadtwinError, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.apps.render import RenderOptions, run_render
from roadtwin_core.render.cameras import RIG_PRESETS, look_from
from roadtwin_core.render.classmap import load_class_map
from roadtwin_core.usd import validate_stage, write_layout

from test_defect_types import assert_valid_defect
from test_ravelling import LANE_W, _strip, pm  # noqa: F401  (pm: the fixture, for these tests too)


@pytest.fixture(scope="module")
def alligator():
    return PluginManager().registry("defect_types")["alligator"]


def _make(t, seed=0, **kw):
    return t.generate(dataclasses.replace(t.Params(), **kw), np.random.default_rng(seed), "a")


@pytest.mark.parametrize("seed", range(4))
def test_sampled_models_meet_the_contract_and_repeat(alligator, seed):
    rng = np.random.default_rng(seed)
    m = alligator.generate(alligator.sample_params(rng), rng, "a")
    assert_valid_defect(m, max_faces=200_000)
    again = np.random.default_rng(seed)
    n = alligator.generate(alligator.sample_params(again), again, "a")
    assert np.array_equal(m.vertices, n.vertices) and np.array_equal(m.faces, n.faces)
    assert m.defect_type == "alligator"


def test_crack_length_per_area_is_a_hexagonal_tilings(alligator):
    """Regular cells (no jitter) of spacing s: a hexagonal tiling holds 2 / s metres of edge per
    square metre, so the ellipse (pi a b) holds 2 pi a b / s of crack; the model's grooved area
    is that length times the groove width, less what the ellipse's edge cuts and the hairline
    breaks leave out (under a third), never more. The grooves stay inside the ellipse, as deep
    as asked."""
    L, W, s, g, D = 3.0, 1.0, 0.2, 0.01, 0.008
    m = _make(alligator, length_m=L, width_m=W, cell_m=s, jitter=0.0, groove_m=g, depth_m=D)
    full = 2 * math.pi * (L / 2) * (W / 2) / s * g
    assert 0.67 * full <= m.area_m2 <= 1.05 * full, (m.area_m2, full)
    assert np.ptp(m.vertices[:, 0]) <= L + g and np.ptp(m.vertices[:, 1]) <= W + g
    assert m.depth_m == pytest.approx(D, rel=0.01)
    finer = _make(alligator, length_m=L, width_m=W, cell_m=s / 2, jitter=0.0, groove_m=g / 2, depth_m=D)
    assert finer.area_m2 == pytest.approx(m.area_m2, rel=0.2)      # twice the length, half the width


def test_is_crack_along_travel_in_the_crack_finish(alligator):
    cmap = load_class_map("road_defects_br")
    assert cmap.plain["alligator"] == "crack"
    assert alligator.along_travel is True and alligator.material == "crack"


@pytest.mark.parametrize("kw, name", [({"cell_m": 0.6, "width_m": 1.0}, "cell_m"),
                                      ({"groove_m": 0.04, "cell_m": 0.2}, "groove_m"),
                                      ({"jitter": 0.5}, "jitter"), ({"depth_m": float("nan")}, "depth_m")])
def test_bad_params_name_the_parameter(alligator, kw, name):
    with pytest.raises(RoadtwinError, match=name):
        _make(alligator, **kw)


def test_composed_and_rendered_its_grooves_are_crack_and_darker_than_the_lane(pm, tmp_path):
    """A 3 m x 0.8 m alligator area in the right wheel path of a straight road composes into a
    stage that validates; through the survey rig from 8 m behind, its pixels are crack under
    road_defects_br and darker than the lane around them (the crack finish)."""
    segs = []
    for i, x in enumerate((0.0, 20.0)):
        x1 = x + 20.0
        segs += [_strip(f"r{i}", "driving", x, x1, -LANE_W, 0.0, np.array([[x, -LANE_W / 2], [x1, -LANE_W / 2]])),
                 _strip(f"l{i}", "driving", x, x1, 0.0, LANE_W, np.array([[x1, LANE_W / 2], [x, LANE_W / 2]]))]
    layout = TownLayout("Town", segs, ComposeRules(defect_count=0, seed=1, surface="flat", models_per_type=1,
                                                   type_weights={"pothole": 1.0}))
    layout.fixed = [FixedDefect("A0", "alligator", {"length_m": 3.0, "width_m": 0.8, "cell_m": 0.2, "groove_m": 0.02,
                                                    "depth_m": 0.008}, x=12.0, y=-LANE_W / 2 - 0.85, seed=0)]
    write_layout(layout, tmp_path / "road.usda")
    town = compose(tmp_path / "road.usda", tmp_path / "town", preview=False, executor="serial", pm=pm).town
    assert not [f for f in validate_stage(town) if f.severity == "Error"]
    rig = RIG_PRESETS["survey"]
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps([{"cam_to_world": look_from((12.0 - 1.5 - 8.0, -LANE_W / 2, rig.height_m), 0.0,
                                                            math.radians(rig.pitch_deg)).tolist()}]))
    out = tmp_path / "r"
    run_render(town, out, RenderOptions(rig="survey", size="512x320", frames=1, poses=poses, formats="mmseg,coco",
                                        executor="serial", classmap="builtin:road_defects_br"), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    (fr,) = meta["frames"]
    (area_id,) = [i["id"] for i in meta["instances"] if i["type"] == "alligator"]
    labels = cv2.imread(str(out / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
    inst = cv2.imread(str(out / fr["files"]["instance"]), cv2.IMREAD_UNCHANGED)
    rgb = cv2.imread(str(out / fr["files"]["rgb"]), cv2.IMREAD_GRAYSCALE).astype(float)
    cmap = load_class_map("road_defects_br")
    sel = inst == area_id
    assert sel.sum() > 100                                           # the grooves reach many pixels
    assert (labels[sel] == cmap.classes.index("crack")).mean() > 0.95
    lane = (labels == cmap.classes.index("ego_lane")) & ~sel
    assert np.median(rgb[sel]) < 0.9 * np.median(rgb[lane])
