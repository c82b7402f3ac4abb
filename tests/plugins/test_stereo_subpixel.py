"""Sub-pixel refinement of SGBM's disparity (issue 20, item 5) against closed-form truth: a
rendered rectified pair (``roadtwin_stereo.synthetic.BowlScene.stereo_pair``: a random texture
fixed on the surface, 2 grey levels of sensor noise) of a road plane seen 30 deg from its normal
with a paraboloid pothole, whose exact disparity comes from ray-surface intersection. The plane's
disparity is a sub-pixel ramp along the rows (20-28 px), so every fractional part occurs: SGBM's
pixel locking shows as a large error, the refinement must remove most of it, without bias, and
keep the pothole's dip.
"""
from __future__ import annotations

import numpy as np
import pytest

import roadtwin_stereo as rs
from roadtwin_stereo.synthetic import BowlScene

SCENE = dict(f=400.0, width=320, height=240, tilt_deg=30.0, distance=2.0, radius=0.3)

@pytest.fixture(scope="module")
def pair():
    sc = BowlScene(depth=0.03, **SCENE)
    left, right = sc.stereo_pair(seed=4, texture_m=0.008)
    sgbm = rs.sgbm_disparity(left, right, 48)
    inner = np.zeros(sgbm.shape, bool)
    inner[8:-8, 56:-8] = True  # away from the left band SGBM cannot match and the borders
    return sc, left, right, sgbm, inner & np.isfinite(sgbm)

def test_refinement_removes_pixel_locking(pair):
    sc, left, right, sgbm, m = pair
    true = sc.disparity()
    refined = rs.refine_disparity(left, right, sgbm)
    e_sgbm, e_ref = np.abs(sgbm - true)[m], np.abs(refined - true)[m]
    assert np.median(e_sgbm) > 0.1                    # SGBM: pixel-locked (the reason for all this)
    assert np.median(e_ref) < 0.3 * np.median(e_sgbm)
    assert np.median(e_ref) < 0.04
    assert abs(np.mean((refined - true)[m])) < 0.01   # no bias
    # pixel locking: SGBM's fractional parts crowd at whole pixels, the truth's are uniform
    frac = lambda x: np.abs(x - np.round(x))[m]  # noqa: E731
    assert np.mean(frac(sgbm) < 0.125) > 0.45
    assert abs(np.mean(frac(refined) < 0.125) - np.mean(frac(true) < 0.125)) < 0.1

def test_refinement_keeps_the_pothole_dip(pair):
    sc, left, right, sgbm, m = pair
    plane = BowlScene(depth=0.0, **SCENE).disparity()
    true_dip = plane - sc.disparity()
    bowl = m & (true_dip > 0.5 * true_dip.max())
    refined_dip = plane - rs.refine_disparity(left, right, sgbm)
    assert bowl.sum() > 1000
    assert np.mean(refined_dip[bowl]) == pytest.approx(np.mean(true_dip[bowl]), rel=0.15)
    assert np.median(np.abs(refined_dip - true_dip)[bowl]) < 0.5 * np.median(np.abs(plane - sgbm - true_dip)[bowl])

def test_refinement_keeps_invalid_pixels_and_checks_sizes(pair):
    _, left, right, sgbm, _ = pair
    refined = rs.refine_disparity(left, right, sgbm)
    assert np.array_equal(np.isnan(refined), np.isnan(sgbm))
    flat = np.full(left.shape, 128, np.uint8)          # no texture: nothing to refine, SGBM's kept
    d = np.full(left.shape, 20.0)
    assert np.array_equal(rs.refine_disparity(flat, flat, d), d)
    with pytest.raises(ValueError, match="differ in size"):
        rs.refine_disparity(left, right[:-1], sgbm)

def _grazing_scene(potholes):
    """The loop's rig seen in closed form: 0.95 m up, pitched 12 deg down, f = 763 px (80 deg
    over 1280 px), 12 cm baseline; the 473 rows that see the road within ~15 m (principal point
    moved as bench/loop.py's crop moves it); a flat road with 10 cm deep, 30 cm radius bowls."""
    from roadtwin_stereo.synthetic import RoadScene

    sc = RoadScene(f=763.0, width=1280, height=473, baseline=0.12, tilt_deg=78.0,
                   distance=0.95 / np.cos(np.radians(78.0)), cross_slope=0.0, waves=(), potholes=potholes)
    sc.K[1, 2] = 112.5
    return sc

@pytest.mark.slow
def test_refinement_on_the_loops_rig_far_potholes():
    """Potholes 5, 7.5 and 10 m ahead: a 0.4-1 px dip. The refined map's noise off the potholes
    must be a fraction of SGBM's, and each pothole's inner dip (r < R/2) within 0.07 px of the
    truth. The default window (6 x 2 px) was chosen on this scene (seed 11): the best ratio of
    the 10 m dip to the road noise among windows whose dips stay within 0.06 px."""
    pots = ((0.0, 0.5, 0.3, 0.1), (-0.8, 3.0, 0.3, 0.1), (0.8, 5.5, 0.3, 0.1))
    sc, flat = _grazing_scene(pots), _grazing_scene(())
    left, right = sc.stereo_pair(seed=11, texture_m=0.02)
    true, plane = sc.disparity(), flat.disparity()
    sgbm = rs.sgbm_disparity(left, right, 96)
    refined = rs.refine_disparity(left, right, sgbm)
    m = np.isfinite(sgbm)
    m[:, :100] = False
    off = m & ~np.any(sc.pothole_masks(), axis=0)
    rsig = lambda e: 1.4826 * np.median(np.abs(e - np.median(e)))  # noqa: E731
    assert rsig((refined - true)[off]) < 0.35 * rsig((sgbm - true)[off])
    for px, py, r, dd in pots:
        inner = m & _grazing_scene(((px, py, r / 2, dd),)).pothole_masks()[0]
        assert np.mean((plane - refined)[inner]) == pytest.approx(np.mean((plane - true)[inner]), abs=0.07)

def test_reject_drops_matches_where_the_views_disagree(pair):
    """A reflection of other texture seen by the right camera only (view-dependent appearance:
    the two views disagree there) leaves a large fit residual; ``reject`` must return many of
    those matches invalid and keep nearly all the others, as accurate as before."""
    sc, left, right, _, m = pair
    true = sc.disparity()
    v, u = np.mgrid[0:right.shape[0], 0:right.shape[1]]
    r = np.hypot(u - 200.0, v - 120.0)
    w = 0.7 * np.clip((14 - r) / 3, 0, 1)
    right2 = np.clip(right * (1 - w) + np.roll(left, 3, axis=1) * w, 0, 255).astype(np.uint8)
    sgbm2 = rs.sgbm_disparity(left, right2, 48)
    plain = rs.refine_disparity(left, right2, sgbm2)
    kept = rs.refine_disparity(left, right2, sgbm2, reject=(1.5, 2.5))
    near, far = m & np.isfinite(plain) & (r < 10), m & np.isfinite(plain) & (r > 30)
    assert np.isnan(kept[near]).mean() > 0.25          # the disagreeing matches: many rejected
    assert np.isnan(kept[far]).mean() < 0.03           # the rest kept
    assert np.nanmedian(np.abs(kept - true)[far]) <= 1.01 * np.median(np.abs(plain - true)[far])
