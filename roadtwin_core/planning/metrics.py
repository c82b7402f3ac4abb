"""The paper's path metrics (length, deviation, smoothness, clearance, wheel in defect)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .grid import GridMap
from .collision import CollisionChecker
from .footprint import Footprint, transform, wrap_angle
from .reference import polyline_length, reference_path


@dataclass
class PathMetrics:
    length_m: float
    reference_length_m: float
    deviation_pct: float
    total_turn_rad: float
    smoothness_rad_per_m: float
    mean_clearance_m: float
    min_clearance_m: float
    wheel_in_defect: bool
    defects_under_wheels: list[str]
    body_over_defect: bool
    off_road: bool
    collision_free: bool

    def as_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}


def heading_changes(poses: np.ndarray) -> tuple[float, float]:
    """(length, total |heading change|) of a path's segments (zero-length ones skipped)."""
    xy = np.asarray(poses, dtype=np.float64)[:, :2]
    d = np.diff(xy, axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    keep = seg > 1e-9
    heading = np.arctan2(d[keep, 1], d[keep, 0])
    turn = float(np.abs(wrap_angle(np.diff(heading))).sum()) if len(heading) > 1 else 0.0
    return float(seg.sum()), turn


def resample_by_length(poses: np.ndarray, step: float) -> np.ndarray:
    """Poses every ``step`` metres of rear-axle travel (yaw interpolated within each segment)."""
    p = np.asarray(poses, dtype=np.float64)
    d = np.diff(p[:, :2], axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    keep = np.flatnonzero(seg > 1e-9)
    if len(keep) == 0:
        return p[:1].copy()
    s = np.concatenate([[0.0], np.cumsum(seg[keep])])
    q = np.linspace(0.0, s[-1], max(2, int(math.ceil(s[-1] / step)) + 1))
    k = np.clip(np.searchsorted(s, q, side="right") - 1, 0, len(keep) - 1)
    t = ((q - s[k]) / seg[keep][k])[:, None]
    a, b = p[keep][k], p[keep + 1][k]
    out = a + t * (b - a)
    out[:, 2] = a[:, 2] + t[:, 0] * wrap_angle(b[:, 2] - a[:, 2])
    return out


def path_metrics(grid: GridMap, poses: np.ndarray, footprint: Footprint, collision: str = "wheel",
                 reference_length: float | None = None) -> PathMetrics:
    """The paper's metrics (see the module docstring) of a path; ``collision`` picks the level
    that ``collision_free`` is judged at."""
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    length, turn = heading_changes(poses)
    if reference_length is None:
        reference_length = polyline_length(reference_path(grid, poses[0], poses[-1]))
    dev = 100.0 * (length / reference_length - 1.0) if reference_length > 1e-9 else 0.0
    wheel = CollisionChecker(grid, footprint, "wheel")
    body = CollisionChecker(grid, footprint, "body")
    dense = wheel.densify(poses)
    # Tire samples on defect cells / off the lanes, anywhere along the motion.
    tire = transform(dense, wheel.tire_local)
    ix, iy = grid.world_to_cell(tire)
    inside = grid.inside(ix, iy)
    cx, cy = np.clip(ix, 0, grid.shape[1] - 1), np.clip(iy, 0, grid.shape[0] - 1)
    under = np.where(inside, grid.defect_index[cy, cx], -1)
    off = ~inside | ~grid.drivable[cy, cx]
    hit_ids = sorted({grid.defect_name(int(k)) for k in np.unique(under[under >= 0])})
    body_hit = bool(grid.sample(grid.defect, transform(dense, body.motion_local), False).any())
    checker = wheel if collision == "wheel" else body
    travel = resample_by_length(poses, grid.resolution / 2)
    clear = grid.clearance(footprint.wheel_centres(travel))
    clear_all = grid.clearance(footprint.wheel_centres(dense))
    return PathMetrics(
        length_m=length, reference_length_m=float(reference_length), deviation_pct=float(dev),
        total_turn_rad=turn, smoothness_rad_per_m=turn / length if length > 1e-9 else 0.0,
        mean_clearance_m=float(clear.mean()), min_clearance_m=float(min(clear.min(), clear_all.min())),
        wheel_in_defect=bool(hit_ids), defects_under_wheels=hit_ids, body_over_defect=body_hit,
        off_road=bool(off.any()), collision_free=checker.path_free(poses))

