"""The stereo detector's region rule (issue 20, item 5: StereoDefectsParams.k_region, segment.py
step 5c) against closed-form truth.

bench/loop_missed.py showed why the loop misses potholes: far ones are shallow dips over many
pixels (0.3-0.6 px over 500-2000 px), measured correctly by the matcher but 5-9 noise units at
their deepest, under the peak rule's 10. Scene (``roadtwin_stereo.synthetic.RoadScene``): a camera
0.95 m above a road with a 2 % cross-slope and mm undulations, pitched 20 deg down, a 4 cm deep
paraboloid pothole of 0.45 m radius about 5 m ahead; exact disparity by ray-surface intersection
plus matcher-like noise (0.08 px, correlated over 3 px along the rows and 1 across, as SGBM's and
the Lucas-Kanade window's errors are). The true mask is the set of pixels whose ray meets the road
inside the rim.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import roadtwin_stereo as rs
from roadtwin_stereo.synthetic import RoadScene

HEIGHT_M, TILT_DEG = 0.95, 70.0
POTHOLE = (0.2, 2.5, 0.45, 0.04)   # x, y (along the road from the optical axis' foot), R, depth (m)


@pytest.fixture(scope="module")
def scene():
    sc = RoadScene(width=640, height=240, f=500.0, baseline=0.12, tilt_deg=TILT_DEG, roll_deg=0.5,
                   distance=HEIGHT_M / np.cos(np.radians(TILT_DEG)), cross_slope=0.02,
                   waves=((0.004, 6.0, 0.3), (0.002, 2.0, 1.1)), potholes=(POTHOLE,))
    return sc, sc.disparity(), sc.pothole_masks()[0]


def _noisy(d: np.ndarray, seed: int) -> np.ndarray:
    n = gaussian_filter(np.random.default_rng(seed).normal(size=d.shape), (1.0, 3.0))
    return d + 0.08 * n / n.std()


def _run(sc, disp, **params):
    rec = rs.StereoDefects()
    return rec.run({"disparity": disp, "K": sc.K, "baseline": sc.baseline},
                   rec.Params(texture=False, grid_m=0.02, **params))


@pytest.mark.parametrize("seed", [0, 1])
def test_far_shallow_pothole_found_by_its_mean(scene, seed):
    """The peak rule alone (k_region 0, the detector before) misses it; with the shipped default
    it is found (most of its true pixels), nothing else is, and its mesh depth is within 5 mm."""
    sc, d, truth = scene
    disp = _noisy(d, seed)
    before = _run(sc, disp, k_region=0.0)
    assert (before.labels[truth] > 0).mean() < 0.1
    after = _run(sc, disp)
    assert (after.labels[truth] > 0).mean() >= 0.5
    false = [i for i in range(1, int(after.labels.max()) + 1) if truth[after.labels == i].mean() < 0.5]
    assert not false
    on = [m for m in after.models if (after.labels == m.params["instance"])[truth].any()]
    assert len(on) == 1 and abs(on[0].depth_m - POTHOLE[3]) <= 0.005


def test_normalised_maps_unaffected(scene):
    """A transformed, normalised map (the 13 real frames) has no metric floor to guard the rule:
    there it is not applied, whatever k_region."""
    sc, d, _ = scene
    dt, _ = rs.transform_disparity(_noisy(d, 0))
    rec = rs.StereoDefects()
    labels = [rec.run({"disparity": dt, "transformed": True}, rec.Params(k_region=k, texture=False)).labels
              for k in (0.0, 12.0, 3.0)]
    assert np.array_equal(labels[0], labels[1]) and np.array_equal(labels[0], labels[2])
