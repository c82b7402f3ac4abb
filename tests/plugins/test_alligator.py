"""Alligator cracking (plugins/roadtwin_defects/alligator.py): a wheel-path area of small crack
cells, one simple polygon (the DefectModel contract), with as much crack per square metre as a
hexagonal tiling of its cell size has (a closed form), labelled crack under road_defects_br."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from roadtwin_core import FixedDefect, PluginManager, RoadtwinError
from roadtwin_core.render.classmap import load_class_map
from roadtwin_core.usd import validate_stage

from test_defect_types import assert_valid_defect
from test_ravelling import LANE_W, pm, survey_frame, wheel_path_town  # noqa: F401  (pm: the fixture, here too)


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
    area = FixedDefect("A0", "alligator", {"length_m": 3.0, "width_m": 0.8, "cell_m": 0.2, "groove_m": 0.02,
                                           "depth_m": 0.008}, x=12.0, y=-LANE_W / 2 - 0.85, seed=0)
    town = wheel_path_town(pm, tmp_path, area, shoulder=False)
    assert not [f for f in validate_stage(town) if f.severity == "Error"]
    sel, labels, rgb, cmap = survey_frame(town, pm, tmp_path / "frame", 12.0 - 1.5 - 8.0, "512x320", "alligator")
    assert sel.sum() > 100                                           # the grooves reach many pixels
    assert (labels[sel] == cmap.classes.index("crack")).mean() > 0.95
    lane = (labels == cmap.classes.index("ego_lane")) & ~sel
    assert np.median(rgb[sel]) < 0.9 * np.median(rgb[lane])
