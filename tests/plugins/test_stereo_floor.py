"""The stereo detector's physical floor (issue 20, item 5) against closed-form truth.

On a clean disparity map (what sub-pixel matching gives) the detector's noise-relative thresholds
fall until benign road shape passes: a wide 6 mm sag of the road is then a "defect" as much as a
4 cm pothole. The floor (StereoDefectsParams.floor_depth_m: metres below the local road model)
must drop the sag and keep the pothole, whose mesh depth stays within tolerance of the truth.
Scene: ``roadtwin_stereo.synthetic.RoadScene``, a camera 1.0 m above a road with a 2 % cross-slope
and a 4 mm undulation, exact disparity by ray-surface intersection plus 0.005 px noise.
"""
from __future__ import annotations

import numpy as np
import pytest

import roadtwin_stereo as rs
from roadtwin_stereo.road_model import metric_road_depth
from roadtwin_stereo.segment import road_residual
from roadtwin_stereo.synthetic import RoadScene

POTHOLE = (0.35, -0.2, 0.2, 0.04)   # x, y, R, depth (m)
SAG = (-0.4, 1.0, 0.35, 0.006)      # a wide, shallow dip of the road: not a defect

@pytest.fixture(scope="module")
def scene():
    sc = RoadScene(width=400, height=240, f=300.0, baseline=0.12, tilt_deg=60, roll_deg=1.0, distance=2.0,
                   cross_slope=0.02, waves=((0.004, 3.0, 0.3),), potholes=(POTHOLE, SAG))
    return sc, sc.disparity(0.005, seed=1), sc.pothole_masks()

def _run(sc, disp, **params):
    rec = rs.StereoDefects()
    return rec.run({"disparity": disp, "K": sc.K, "baseline": sc.baseline}, rec.Params(grid_m=0.02, **params))

def test_metric_depth_and_area_closed_form(scene):
    """The camera height from the road's disparity plane, the depth of a paraboloid (its 90th
    percentile over the rim is 0.9 D: depth is uniform in [0, D] over the disc) and its area."""
    sc, disp, (pothole, _) = scene
    dt, _ = rs.transform_disparity(disp)
    z, valid, sigma = road_residual(dt, with_sigma=True)
    depth, area = metric_road_depth(z * sigma, disp, valid & (z > -3), sc.K, sc.baseline)
    assert np.percentile(depth[pothole], 90) == pytest.approx(0.9 * POTHOLE[3], rel=0.15)
    assert np.nansum(area[pothole]) == pytest.approx(np.pi * POTHOLE[2] ** 2, rel=0.05)
    assert abs(np.median(depth[valid & ~pothole])) < 0.001  # the road is at depth 0

def test_without_floor_the_sag_passes(scene):
    """The clean map's noise unit is tiny: the sag reaches the noise-relative thresholds (what the
    loop showed as false detections on clean maps); this is what the floor is for."""
    sc, disp, (_, sag) = scene
    res = _run(sc, disp, floor_depth_m=0.0, floor_area_m2=0.0)
    assert (res.labels[sag] > 0).mean() >= 0.5

def test_floor_drops_the_sag_keeps_the_pothole(scene):
    sc, disp, (pothole, sag) = scene
    floor = rs.StereoDefects.Params().floor_depth_m
    assert SAG[3] < floor < POTHOLE[3]  # the shipped floor sits between the two
    res = _run(sc, disp, floor_depth_m=floor)
    assert (res.labels[sag] > 0).mean() == 0
    assert (res.labels[pothole] > 0).mean() >= 0.9
    on = [m for m in res.models if (res.labels == m.params["instance"])[pothole].any()]
    assert len(on) == 1 and abs(on[0].depth_m - POTHOLE[3]) <= 0.005

def test_floor_not_applied_to_transformed_maps(scene):
    """A transformed (normalised) map has no metric scale: the floor cannot apply, and the
    real frames' results (../shared/data/stereo_pothole are such maps) do not change."""
    sc, disp, _ = scene
    dt, _ = rs.transform_disparity(disp)
    rec = rs.StereoDefects()
    a = rec.run({"disparity": dt, "transformed": True}, rec.Params(floor_depth_m=0.0)).labels
    b = rec.run({"disparity": dt, "transformed": True}, rec.Params(floor_depth_m=0.05)).labels
    assert a.max() >= 1 and np.array_equal(a, b)
