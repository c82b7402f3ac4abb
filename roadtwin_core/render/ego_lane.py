"""Ego-lane labels: which pixels show the road surface of the camera's own lane ahead.

The real survey data (road_defects_br) labels the vehicle's lane region as its own class ("ego
lane"); a synthetic frame gets the same label from geometry, not from paint: every pixel's
world point (from the depth map and the camera) is projected onto the lane centreline, and the
pixel is ego lane when its lateral distance is at most half the lane width and it lies ahead of
the camera along the lane (and before the end of the given centreline). Defect pixels inside
the lane are ego lane too; a class map puts defect classes over it, as the real labels do.

numpy + scipy: a k-d tree over the centreline densified to ``step_m``, then the exact
projection onto the two polyline pieces next to the nearest sample.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import RoadtwinError
from .cameras import Camera, pixel_grid


def world_points(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) world points of a z-depth map (0 or non-finite: no hit, NaN out)."""
    k = camera.intrinsics
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (k.height, k.width):
        raise RoadtwinError(f"depth map is {depth.shape[1]}x{depth.shape[0]}, the camera is {k.width}x{k.height}")
    _, _, xn, yn = pixel_grid(k)
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    pc = np.stack([xn * z, yn * z, z], axis=-1)
    return pc @ camera.rotation.T + camera.position


BRUTE_FORCE_PAIRS = 100_000     # points x samples up to which the nearest sample is found without a k-d tree


def _densify(line: np.ndarray, step_m: float) -> tuple[np.ndarray, np.ndarray]:
    seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
    line = line[np.concatenate([[True], seg > 1e-9])]
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
    s = np.unique(np.concatenate([np.arange(0.0, cum[-1], step_m), cum]))
    return np.column_stack([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])]), s


def lane_coordinates(xy: np.ndarray, lane_xy: np.ndarray, step_m: float = 0.25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arc length along the lane, signed lateral offset (left positive) and whether the foot
    of the perpendicular falls inside the polyline (not beyond either end) for points (N,2)."""
    lane_xy = np.asarray(lane_xy, dtype=np.float64).reshape(-1, 2)
    if len(lane_xy) < 2:
        raise RoadtwinError("ego lane: the lane centreline needs at least 2 points")
    pts, cum = _densify(lane_xy, step_m)
    if len(pts) < 2:
        raise RoadtwinError("ego lane: the lane centreline has zero length")
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) * len(pts) <= BRUTE_FORCE_PAIRS:     # a camera's own position: a tree costs more than it saves
        k = np.argmin((xy[:, None, 0] - pts[None, :, 0]) ** 2 + (xy[:, None, 1] - pts[None, :, 1]) ** 2, axis=1)
    else:
        _, k = cKDTree(pts).query(xy)
    x, y = xy[:, 0], xy[:, 1]
    # per piece once (not per point): start, direction, squared length (the same numbers the
    # per-point form computed, component by component, so the results are bit for bit the same)
    px, py = pts[:-1, 0], pts[:-1, 1]
    abx_all, aby_all = pts[1:, 0] - px, pts[1:, 1] - py
    ll_all = np.maximum(abx_all * abx_all + aby_all * aby_all, 1e-24)
    len_all = np.sqrt(ll_all)
    best_d2 = np.full(len(xy), np.inf)
    best_s = np.zeros(len(xy))
    best_lat = np.zeros(len(xy))
    inside = np.zeros(len(xy), dtype=bool)
    for j in (np.maximum(k - 1, 0), np.minimum(k, len(pts) - 2)):     # pieces before and after the sample
        abx, aby, ll = abx_all[j], aby_all[j], ll_all[j]
        apx, apy = x - px[j], y - py[j]
        t_raw = (apx * abx + apy * aby) / ll
        t = np.clip(t_raw, 0.0, 1.0)
        dx, dy = apx - t * abx, apy - t * aby
        d2 = dx * dx + dy * dy
        better = d2 < best_d2
        best_d2 = np.where(better, d2, best_d2)
        best_s = np.where(better, cum[j] + t * len_all[j], best_s)
        cross = abx * apy - aby * apx
        best_lat = np.where(better, np.sign(cross) * np.sqrt(d2), best_lat)
        ok = ((t_raw >= 0) | (j > 0)) & ((t_raw <= 1) | (j < len(pts) - 2))
        inside = np.where(better, ok, inside)
    return best_s, best_lat, inside


def ego_lane_mask(camera: Camera, depth: np.ndarray, lane_xy: np.ndarray, lane_width_m: float, *,
                  surface: np.ndarray | None = None, max_distance_m: float | None = None) -> np.ndarray:
    """Boolean (H, W) mask of the ego lane: pixels whose world point lies within
    ``lane_width_m / 2`` of the lane centreline ``lane_xy`` (XY, travel order, from about the
    camera onwards), ahead of the camera along the lane, and on the road ``surface`` (a mask of
    road/defect/marking pixels; all hit pixels when None), no further than ``max_distance_m``
    from the camera in plan if given."""
    if not (np.isfinite(lane_width_m) and lane_width_m > 0):
        raise RoadtwinError(f"ego lane: lane width must be > 0 m, got {lane_width_m}")
    pts = world_points(camera, depth)
    valid = np.isfinite(pts[..., 0])
    if surface is not None:
        surface = np.asarray(surface, dtype=bool)
        if surface.shape != valid.shape:
            raise RoadtwinError(f"ego lane: surface mask shape {surface.shape} differs from the depth map's {valid.shape}")
        valid &= surface
    mask = np.zeros(valid.shape, dtype=bool)
    if not valid.any():
        return mask
    xy = pts[valid][:, :2]
    # only points near the lane's bounding box can be within half a lane width of it: the rest
    # are left out before the (per-point, so unchanged) projection, ~2-3x fewer on a survey frame
    near = _near_box(xy, lane_xy, lane_width_m / 2)
    xy = xy[near]
    s, lat, inside = lane_coordinates(xy, lane_xy)
    s_cam, _, _ = lane_coordinates(camera.position[None, :2], lane_xy)
    keep = inside & (np.abs(lat) <= lane_width_m / 2) & (s >= s_cam[0])
    if max_distance_m is not None:
        keep &= np.linalg.norm(xy - camera.position[:2], axis=1) <= max_distance_m
    kept = np.zeros(len(near), dtype=bool)
    kept[near] = keep
    mask[valid] = kept
    return mask


def _near_box(xy: np.ndarray, lane_xy: np.ndarray, radius_m: float) -> np.ndarray:
    """Points within ``radius_m`` (+ 1 mm for rounding) of the lane polyline's bounding box: a
    superset of the points within ``radius_m`` of the polyline (every point of it lies in the box)."""
    lane_xy = np.asarray(lane_xy, dtype=np.float64).reshape(-1, 2)
    lo, hi = lane_xy.min(axis=0) - (radius_m + 1e-3), lane_xy.max(axis=0) + (radius_m + 1e-3)
    return (xy[:, 0] >= lo[0]) & (xy[:, 0] <= hi[0]) & (xy[:, 1] >= lo[1]) & (xy[:, 1] <= hi[1])
