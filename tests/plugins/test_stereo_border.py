"""Regions cut by the map's edge (StereoDefectsParams.border_px; issue 20, item 5).

On bench/loop.py's tuning town most false detections touch the crop's top row, where the local
road model has no road beyond the edge (bench/loop_false_detections.py). With ``border_px`` a
region reaching the edge is dropped and one inside the map is kept unchanged. Truth: a road
residual (in noise sigmas) with two discs 20 sigma deep, one whole, one cut by the top edge.
"""
from __future__ import annotations

import numpy as np

import roadtwin_stereo as rs
from roadtwin_stereo.segment import SegmentParams, segment_residual

H, W, R = 120, 200, 15


def _residual():
    v, u = np.mgrid[:H, :W]
    inside = (u - 60) ** 2 + (v - 70) ** 2 <= R * R    # whole
    cut = (u - 150) ** 2 + (v - 5) ** 2 <= R * R        # its centre 5 px below the top row
    z = np.random.default_rng(0).normal(0, 1, (H, W)) * 0.3
    z[inside | cut] -= 20.0
    return z, np.ones((H, W), bool), inside, cut


def test_edge_region_dropped_inside_region_kept():
    z, valid, inside, cut = _residual()
    keep_all = segment_residual(z, valid, SegmentParams())
    cleared = segment_residual(z, valid, SegmentParams(border_px=3))
    assert (keep_all[cut] > 0).mean() >= 0.9 and (keep_all[inside] > 0).mean() >= 0.9
    assert (cleared[cut] > 0).sum() == 0 and cleared.max() == 1
    np.testing.assert_array_equal(cleared > 0, (keep_all > 0) & ~cut & (np.abs(keep_all - keep_all[inside][0]) == 0))


def test_default_keeps_edge_regions():
    assert rs.StereoDefects.Params().border_px == 0 and SegmentParams().border_px == 0
