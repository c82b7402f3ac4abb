"""Which lane a camera drives in (for the ego-lane class of frames the view sampler did not place)."""
from __future__ import annotations

import numpy as np

from ...render.view_sampler import project_to_lane

__all__ = ["nearest_lane"]


def nearest_lane(lanes, cam_to_world: np.ndarray, max_offset_m: float):
    """(lane, s) of the chained lane a camera drives in: the nearest centreline within
    ``max_offset_m`` whose travel direction agrees with the camera's heading; None if none."""
    f = cam_to_world[:3, 2]
    h = np.array([f[0], f[1]])
    if np.linalg.norm(h) < 1e-9:
        return None
    xy = cam_to_world[:2, 3]
    best = None
    for lane in lanes:
        s, lat = project_to_lane(lane, xy[None])
        d = abs(float(lat[0]))
        heading = float(lane.heading(np.array([s[0]]), window=2.0)[0])
        if d <= max_offset_m and np.dot(h, [np.cos(heading), np.sin(heading)]) > 0 and (best is None or d < best[2]):
            best = (lane, float(s[0]), d)
    return None if best is None else best[:2]
