"""The stereo detector's local, robust road model (issue 20, item 5) against closed-form truth:
an undulating road (ISO 8608 class C-D undulation amplitudes along the road, a 2.5 % cross-slope
and a 2 % crown, a camera 1.2 m up looking 30 deg down with 1 deg roll) with four paraboloid
potholes 1.5-5 m ahead, exact disparity by ray-surface intersection plus 0.05 px noise
(``roadtwin_stereo.synthetic.RoadScene``). The true mask of each pothole is the set of pixels
whose ray meets the road inside its rim.

A global quadratic road leaves the undulation in the residual and measures its thresholds in
that inflated unit: it finds none of the four. The local model must find each one near its true
size and nothing else.
"""
from __future__ import annotations

import numpy as np
import pytest

import roadtwin_stereo as rs
from roadtwin_stereo.road_model import row_levels, tile_background
from roadtwin_stereo.segment import SegmentParams, segment_defects
from roadtwin_stereo.synthetic import RoadScene

POTHOLES = ((-0.6, -0.6, 0.2, 0.04), (0.7, 0.3, 0.25, 0.05), (-0.2, 1.6, 0.3, 0.06), (0.9, 3.2, 0.3, 0.05))

@pytest.fixture(scope="module")
def undulating():
    sc = RoadScene(width=320, height=240, f=267.0, baseline=0.12, tilt_deg=60, roll_deg=1.0, distance=2.4,
                   cross_slope=0.025, crown=0.02, crown_x=0.8, potholes=POTHOLES)
    dt, _ = rs.transform_disparity(sc.disparity(0.05, seed=1))
    return sc.pothole_masks(), dt

def _per_pothole(labels: np.ndarray, masks: list[np.ndarray]) -> tuple[list[float], list[float], int]:
    """Share of each pothole's true pixels detected, detected area of the instances on it over
    its true area, and the number of detected instances lying mostly off every pothole."""
    det = labels > 0
    recall = [float(det[m].mean()) for m in masks]
    area = [sum(int((labels == i).sum()) for i in np.unique(labels[m]) if i > 0) / m.sum() for m in masks]
    truth = np.any(masks, axis=0)
    false = sum(1 for i in range(1, int(labels.max()) + 1) if truth[labels == i].mean() < 0.5)
    return recall, area, false

def test_undulating_road_every_pothole_found_at_true_size(undulating):
    masks, dt = undulating
    recall, area, false = _per_pothole(segment_defects(dt), masks)
    print("recall", np.round(recall, 2), "area ratio", np.round(area, 2), "false", false)
    assert min(recall) >= 0.5                       # every pothole found (most of its pixels)
    assert all(0.5 <= a <= 1.5 for a in area)       # footprint within a factor 1.5 of the truth
    assert false == 0

def test_global_quadratic_misses_them(undulating):
    """What the issue reports, reproduced: the quadratic's noise unit is inflated by the
    undulation, so the same thresholds find (almost) nothing."""
    masks, dt = undulating
    recall, _, _ = _per_pothole(segment_defects(dt, SegmentParams(road_model="quadratic")), masks)
    assert sum(r >= 0.5 for r in recall) <= 1

def test_tile_background_recovers_a_smooth_road_under_a_masked_hole():
    """Closed form: a tilted, gently curved field plus a bowl 30 px wide; with the bowl masked
    the tile model interpolates the field under it (error < 5 % of the field's range)."""
    h, w = 240, 320
    v, u = np.mgrid[0:h, 0:w].astype(float)
    field = 0.3 * np.sin(2 * np.pi * u / 400) + 0.002 * v
    bowl = np.hypot(u - 160, v - 120) < 15
    e = field - 2.0 * bowl
    bg = tile_background(e, ~bowl, tile_px=30)
    err = np.abs(bg - field)
    assert err[bowl].max() < 0.05 * np.ptp(field)
    assert np.percentile(err, 99) < 0.05 * np.ptp(field)

def test_row_levels_remove_stripes_not_a_pothole():
    """Constant-along-row stripes (SGBM pixel locking) are taken out; a pothole covering a
    third of its rows is left whole."""
    h, w = 120, 300
    v, u = np.mgrid[0:h, 0:w].astype(float)
    stripes = 0.2 * np.sin(2 * np.pi * v / 7)
    hole = (np.abs(u - 150) < 50) & (np.abs(v - 60) < 20)
    r = stripes - 1.0 * hole
    lev = row_levels(r, np.ones_like(hole))
    assert np.abs(lev - stripes[:, 0]).max() < 1e-9
    assert np.allclose((r - lev[:, None])[hole], -1.0)
