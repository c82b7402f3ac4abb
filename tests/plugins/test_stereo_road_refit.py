"""The local road model's refit (issue 20, item 5; road_model.py step 5, SegmentParams.refit_k)
against closed-form truth.

bench/loop_missed.py measured that the local road model absorbs part of a pothole it does not
mask (one under ``mask_k``, 10 noise units): the pothole pulls its tiles and rows down and its
residual comes out a median 28 % shallower than the measured dip. Scene
(``roadtwin_stereo.synthetic.RoadScene``, as tests/plugins/test_stereo_region.py): a camera 0.95
m above a road with a 2 % cross-slope and mm undulations, a 4.5 cm paraboloid pothole of 0.45 m
radius about 5 m ahead, matcher-like noise (0.08 px, correlated over 3 px along the rows). The
reference is independent of the detector: the exact disparity of the same road without the
pothole (ray-surface intersection) minus that with it, smoothed as the detector smooths its
residual (2 px). A dip in px is the depth below the road over ``d / H`` along the ray, so the
ratio of measured to true dip is the ratio of measured to true depth.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import roadtwin_stereo as rs
from roadtwin_stereo.segment import SegmentParams, road_residual
from roadtwin_stereo.synthetic import RoadScene

HEIGHT_M, TILT_DEG = 0.95, 70.0
POTHOLE = (0.2, 2.5, 0.45, 0.045)  # x, y, R, depth (m): 8-10 noise units at its deepest
SEEDS = range(5)


def _scene(potholes) -> RoadScene:
    return RoadScene(width=640, height=240, f=500.0, baseline=0.12, tilt_deg=TILT_DEG, roll_deg=0.5,
                     distance=HEIGHT_M / np.cos(np.radians(TILT_DEG)), cross_slope=0.02,
                     waves=((0.004, 6.0, 0.3), (0.002, 2.0, 1.1)), potholes=potholes)


@pytest.fixture(scope="module")
def scene():
    d, road = _scene((POTHOLE,)).disparity(), _scene(()).disparity()
    mask = road - d > 1e-9  # the rays that meet the road inside the rim (one pothole in the scene)
    true_dip = gaussian_filter(road - d, 2.0)
    return d, road, mask, true_dip


def _noise(shape, seed: int) -> np.ndarray:
    n = gaussian_filter(np.random.default_rng(seed).normal(size=shape), (1.0, 3.0))
    return 0.08 * n / n.std()


def _residual(disp: np.ndarray, refit_k: float) -> tuple[np.ndarray, float]:
    dt, _ = rs.transform_disparity(disp)
    z, _, sigma = road_residual(dt, SegmentParams(refit_k=refit_k), with_sigma=True)
    return z, sigma


def test_refit_gives_back_the_absorbed_dip(scene):
    """Where the first pass leaves the pothole in the road fit (its peak under mask_k), the
    measured dip is >= 13 % short of the truth before the refit and within 12 % after it (the
    rest: the rim under k_grow stays in the fit, and the noise)."""
    d, _, mask, true_dip = scene
    refit_k = rs.StereoDefects.Params().road_refit_k
    assert 0 < refit_k < SegmentParams().mask_k
    unmasked = 0
    for seed in SEEDS:
        disp = d + _noise(d.shape, seed)
        z0, s0 = _residual(disp, 0.0)
        if -np.percentile(z0[mask], 10) >= SegmentParams().mask_k:
            continue  # the first pass masks it already: nothing absorbed
        unmasked += 1
        z1, s1 = _residual(disp, refit_k)
        before = float(np.mean(-z0[mask] * s0) / np.mean(true_dip[mask]))
        after = float(np.mean(-z1[mask] * s1) / np.mean(true_dip[mask]))
        assert before <= 0.87, (seed, before)
        assert 0.88 <= after <= 1.1, (seed, before, after)
    assert unmasked >= 3


def test_refit_leaves_a_pothole_free_road_alone(scene):
    """On the same road without the pothole, leaving both tails out keeps the road level and the
    candidate share (no runaway on the undulation, no lifted level)."""
    _, road, _, _ = scene
    for seed in (0, 1):
        disp = road + _noise(road.shape, seed)
        z0, s0 = _residual(disp, 0.0)
        z1, s1 = _residual(disp, rs.StereoDefects.Params().road_refit_k)
        assert abs(float(np.median(z1))) < 0.05
        assert (z1 < -3).mean() <= 1.2 * (z0 < -3).mean() + 1e-4
        assert abs(s1 / s0 - 1) < 0.05


def test_normalised_maps_not_refitted(scene):
    """A transformed, normalised map (the 13 real frames: unlabelled dips a refit deepens) is not
    refitted, whatever road_refit_k."""
    d, _, _, _ = scene
    dt, _ = rs.transform_disparity(d + _noise(d.shape, 0))
    rec = rs.StereoDefects()
    labels = [rec.run({"disparity": dt, "transformed": True}, rec.Params(road_refit_k=k, texture=False)).labels
              for k in (0.0, 7.0, 3.0)]
    assert np.array_equal(labels[0], labels[1]) and np.array_equal(labels[0], labels[2])
