"""A photo's camera pitch and height from its lane lines, where the rig is not known per frame.

On a flat road seen by a pinhole camera without roll, the two edges of the labelled lane (the
ego-lane region of a label image) are straight lines meeting at the vanishing point on the
horizon row ``v_h``, and the lane's width in pixels grows linearly below it:

    w(v) = (fx / fy) * (W cos(pitch) / h) * (v - v_h),      tan(pitch) = (c_y - v_h) / fy

(W the lane width in metres, h the camera height). So one frame gives its pitch (from ``v_h``)
and its height (from the slope), i.e. its road homography; the focal length is not observable
from parallel lines on a flat road and comes from the base rig (its field of view). Each edge is
a Huber-robust line (``cv2.fitLine``) through the lane's left / right boundary per row, rows where
the lane leaves the picture dropped. docs/survey_rig.md shows the same geometry over the whole
train set (``bench/estimate_survey_rig.py`` uses these functions).
"""
from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
from scipy import ndimage

from .rectify import PhotoRig


def lane_edges(lane: np.ndarray, margin: int = 2, min_width: int = 6):
    """Rows and left / right edge columns of the lane mask's largest blob (holes, e.g. defects
    inside it, filled), with masks of the rows where each edge is inside the picture."""
    lane = ndimage.binary_fill_holes(lane)
    lab, n = ndimage.label(lane)
    if n == 0:
        return None
    lane = lab == (1 + int(np.argmax(ndimage.sum(lane, lab, range(1, n + 1)))))
    rows = np.flatnonzero(lane.any(1))
    left = np.argmax(lane[rows], axis=1)
    right = lane.shape[1] - 1 - np.argmax(lane[rows, ::-1], axis=1)
    keep_l = (left > margin) & (right - left >= min_width)
    keep_r = (right < lane.shape[1] - 1 - margin) & (right - left >= min_width)
    return rows, left, right, keep_l, keep_r


def fit_edge(rows: np.ndarray, cols: np.ndarray) -> tuple[float, float, float]:
    """x = a + b * v through the edge pixels (Huber-robust), and the RMS residual in pixels."""
    pts = np.column_stack([cols, rows]).astype(np.float32)
    vx, vy, x0, y0 = cv2.fitLine(pts, cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
    b = vx / vy
    a = x0 - b * y0
    resid = cols - (a + b * rows)
    return float(a), float(b), float(np.sqrt(np.mean(resid ** 2)))


def frame_estimate(lane: np.ndarray, min_rows: int = 60, max_rms: float = 3.0) -> dict | None:
    """Horizon row, vanishing column and width slope of one lane mask, or None when its edges
    are not both long straight lines (curves, missing labels)."""
    e = lane_edges(lane)
    if e is None:
        return None
    rows, left, right, kl, kr = e
    if kl.sum() < min_rows or kr.sum() < min_rows:
        return None
    al, bl, rl = fit_edge(rows[kl], left[kl])
    ar, br, rr = fit_edge(rows[kr], right[kr])
    if max(rl, rr) > max_rms or br - bl <= 1e-3:
        return None
    v_h = -(ar - al) / (br - bl)
    return {"v_h": v_h, "u_vp": al + bl * v_h, "slope": br - bl, "rms": max(rl, rr)}


def rig_from_lanes(lane: np.ndarray, base: PhotoRig, lane_width_m: float) -> PhotoRig | None:
    """``base`` with the pitch and height this frame's lane lines say (roll 0), or None when
    the lane edges do not give them (then the caller keeps ``base``)."""
    est = frame_estimate(lane)
    if est is None:
        return None
    h_px, w_px = lane.shape
    k = base.K(w_px, h_px)
    fx, fy, cy = k[0, 0], k[1, 1], k[1, 2]
    pitch = math.atan((cy - est["v_h"]) / fy)              # positive: looking down
    height = (fx / fy) * lane_width_m * math.cos(pitch) / est["slope"]
    if not (0 < pitch < math.pi / 2 and 0.2 < height < 50):
        return None
    return replace(base, name=f"{base.name}:lanes", pitch_deg=-math.degrees(pitch), height_m=height, roll_deg=0.0)
