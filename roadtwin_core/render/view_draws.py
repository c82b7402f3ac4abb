"""The view sampler's geometry for many frames at once (docs/architecture.md, "render"): where a
camera stands on its lane, whether a vehicle stands there, and the road's height and attitude
under the vehicle. Sampling 1,500 views one at a time spent nine ground queries of ~0.1 ms each
on every try; here every try of a round shares one query per wheel position.

Each value equals, to the bit, what the one-frame expressions gave: the same numpy operations
elementwise (a batch only adds rows), the scalar ``math`` trigonometry where the one-frame code
used it, and the same summation order, so batching changes no camera and no byte of a dataset.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .cameras import GroundFn, KeepOut, Lane, vehicle_height

__all__ = ["TRACK_HALF_M", "WHEELBASE_HALF_M", "clear_of", "lane_spots", "road_attitudes"]

WHEELBASE_HALF_M, TRACK_HALF_M = 1.3, 0.8     # as cameras.vehicle_height samples the road
HEADING_WINDOW_M = 2.0                        # a camera's heading: the lane's chord over +-2 m


def lane_spots(lanes: Sequence[Lane], lane_index: np.ndarray, s: np.ndarray,
               lateral: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(heading (N,), plan position (N,2)) of points ``s`` m along lanes ``lane_index``, shifted
    ``lateral`` m to the left of travel."""
    lane_index = np.asarray(lane_index, dtype=np.int64)
    s = np.asarray(s, dtype=np.float64)
    heading, on_lane = np.empty(len(s)), np.empty((len(s), 2))
    for li in np.unique(lane_index):
        rows = np.nonzero(lane_index == li)[0]
        lane = lanes[int(li)]
        heading[rows] = lane.heading(s[rows], window=HEADING_WINDOW_M)
        on_lane[rows] = lane.at(s[rows])
    left = np.array([(-math.sin(h), math.cos(h)) for h in heading.tolist()], dtype=np.float64).reshape(-1, 2)
    return heading, on_lane + np.asarray(lateral, dtype=np.float64)[:, None] * left


def clear_of(keep_out: KeepOut, xy: np.ndarray) -> np.ndarray:
    """Per plan point (N,2), whether it lies outside every disc of ``keep_out`` (``KeepOut.clear``
    of each row)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if not len(keep_out.xy):
        return np.ones(len(xy), dtype=bool)
    d2 = ((keep_out.xy[None, :, :] - xy[:, None, :]) ** 2).sum(axis=2)
    return (d2 >= (keep_out.radius + keep_out.margin_m) ** 2).all(axis=1)


def road_attitudes(ground: GroundFn, xy: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, list, list]:
    """Per vehicle at plan points ``xy`` (N,2) heading ``heading`` (N,): the road height under it
    (``vehicle_height``; NaN off the road) and the grade pitch and crossfall roll (radians) the
    road puts on a body-mounted camera, from the mean height under its front and back (left and
    right) wheels; a side with no road under it counts as level."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    heading = np.asarray(heading, dtype=np.float64).reshape(-1)
    z = vehicle_height(ground, xy, heading)
    trig = [(math.cos(h), math.sin(h)) for h in heading.tolist()]
    forward = np.array(trig, dtype=np.float64).reshape(-1, 2)
    left = np.array([(-s, c) for c, s in trig], dtype=np.float64).reshape(-1, 2)
    wheels = [xy + WHEELBASE_HALF_M * forward + TRACK_HALF_M * left, xy + WHEELBASE_HALF_M * forward - TRACK_HALF_M * left,
              xy - WHEELBASE_HALF_M * forward + TRACK_HALF_M * left, xy - WHEELBASE_HALF_M * forward - TRACK_HALF_M * left]
    fl, fr, bl, br = ground(np.concatenate(wheels)).reshape(4, len(xy))
    front, back = _mean_of_road(fl, fr), _mean_of_road(bl, br)
    left_z, right_z = _mean_of_road(fl, bl), _mean_of_road(fr, br)
    pitch = [math.atan2(d, 2 * WHEELBASE_HALF_M) if math.isfinite(d) else 0.0
             for d in (front - back).tolist()]
    roll = [math.atan2(d, 2 * TRACK_HALF_M) if math.isfinite(d) else 0.0 for d in (left_z - right_z).tolist()]
    return z, pitch, roll


def _mean_of_road(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean of the finite ones of two heights per row (NaN where neither is), as ``ndarray.mean``
    of the finite pair gives it."""
    pair = np.column_stack([a, b])
    ok = np.isfinite(pair)
    both = pair.sum(axis=1) / 2
    return np.where(ok.all(axis=1), both, np.where(ok[:, 0], a, np.where(ok[:, 1], b, np.nan)))
