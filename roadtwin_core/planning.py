"""Defect-aware path planning (the paper's decision-making study): vehicle, collision, metrics.

Everything here works on a :class:`~roadtwin_core.grid.GridMap`; planners are plugins
(``roadtwin_register_planners``) found by name, and use only this module and ``grid``.

Conventions
-----------
A *pose* is ``(x, y, yaw)``: the rear-axle centre in world metres and the heading in radians
from +x, counter-clockwise. A *path* is an (N, 3) array of poses from the start pose to the goal
pose. Between consecutive poses the vehicle moves linearly in x, y and (shortest way round) in
yaw; two poses at the same point are a turn on the spot, which grid planners (A*, RRT*) use at
their corners. :meth:`CollisionChecker.densify` samples that motion so that no footprint point
moves more than half a cell between samples, and both the planners and the metrics check
exactly those samples, so a path a planner accepted is also a path the metrics accept.

Collision (Zhang et al.: "collision is checked per wheel, not for the body")
---------------------------------------------------------------------------
``wheel``: the four tire contact patches (tire width x contact length) must lie on drivable
cells and on no defect cell; a defect may pass between the wheels (the vehicle straddles it).
``body``: the whole vehicle (body rectangle, overhangs included, never narrower than the outer
tire edges) must lie on drivable cells and cover no defect cell. Footprints are sampled with
points (tires and outline every half cell, the inside every 1/1.5 cell, so every cell lying fully
inside the body holds a point); a cell is hit when a sample point falls in it. The body's points
include the tires' and both levels sample motions at the same poses, so a body-level collision-free
path is always wheel-level collision-free too.

Metrics (the paper's three plus two)
------------------------------------
``length_m``; ``deviation_pct`` = 100 (length / reference - 1) with the reference the shortest
drivable path from start to goal ignoring defects (the straight line when it stays on the
lanes, otherwise a string-pulled 8-connected geodesic); ``smoothness_rad_per_m`` = total absolute
heading change of the path's segments / length; ``mean_clearance_m`` and ``min_clearance_m`` =
distance from each wheel's contact centre to the nearest defect cell centre, averaged over the
four wheels at samples every half cell of travel (the minimum also over turns on the spot);
``wheel_in_defect`` = whether any tire sample point lies on a defect cell anywhere on the path.
"""
from __future__ import annotations

import csv
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from .errors import RoadtwinError
from .grid import GridMap

COLLISION_MODES = ("wheel", "body")
WHEEL_NAMES = ("rear-left", "rear-right", "front-left", "front-right")
_INSET = 1e-4  # footprint sample points sit this far inside the rectangle edges


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------------- vehicle
@dataclass(frozen=True)
class Vehicle:
    """The paper's vehicle: 2.0 m track (wheel centre to wheel centre), 3.0 m wheelbase.

    The pose is the rear-axle centre. The body rectangle runs from ``rear_overhang_m`` behind
    the rear axle to ``body_length_m`` ahead of that; it is at least as wide as the outer tire
    edges (track + tire width), so a body-level check always includes the wheel-level one.
    """

    track_m: float = 2.0
    wheelbase_m: float = 3.0
    tire_width_m: float = 0.2
    tire_length_m: float = 0.3
    body_length_m: float = 4.6
    body_width_m: float = 2.2
    rear_overhang_m: float = 0.8
    max_steer_rad: float = 0.6

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if not (math.isfinite(v) and v > 0):
                raise RoadtwinError(f"vehicle: {k} must be a positive finite number, got {v}")
        if self.tire_width_m >= self.track_m:
            raise RoadtwinError("vehicle: tire_width_m must be smaller than track_m")
        if self.body_length_m < self.wheelbase_m + self.rear_overhang_m:
            raise RoadtwinError("vehicle: body_length_m must cover rear overhang + wheelbase")
        if self.max_steer_rad >= math.pi / 2:
            raise RoadtwinError("vehicle: max_steer_rad must be < pi/2")

    @property
    def min_turn_radius_m(self) -> float:
        """Rear-axle turning radius of the kinematic bicycle at full lock."""
        return self.wheelbase_m / math.tan(self.max_steer_rad)

    @property
    def straddle_gap_m(self) -> float:
        """Free width between the inner tire edges (what a defect must be narrower than)."""
        return self.track_m - self.tire_width_m

    def wheel_offsets(self) -> np.ndarray:
        """(4, 2) wheel contact centres in the vehicle frame, in ``WHEEL_NAMES`` order."""
        h, L = self.track_m / 2, self.wheelbase_m
        return np.array([[0.0, h], [0.0, -h], [L, h], [L, -h]])

    def tire_points(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Sample points of the four tire patches (K, 2) and the wheel index of each (K,)."""
        a = _axis(self.tire_length_m, spacing)
        b = _axis(self.tire_width_m, spacing)
        patch = np.stack(np.meshgrid(a, b, indexing="ij"), axis=-1).reshape(-1, 2)
        pts = (self.wheel_offsets()[:, None, :] + patch[None]).reshape(-1, 2)
        return pts, np.repeat(np.arange(4), len(patch))

    def body_rect(self) -> tuple[float, float, float, float]:
        w = max(self.body_width_m, self.track_m + self.tire_width_m) / 2
        return -self.rear_overhang_m, self.body_length_m - self.rear_overhang_m, -w, w

    def body_points(self, spacing: float, outline_only: bool) -> np.ndarray:
        x0, x1, y0, y1 = self.body_rect()
        xs = _axis(x1 - x0, spacing) + (x0 + x1) / 2
        ys = _axis(y1 - y0, spacing) + (y0 + y1) / 2
        if not outline_only:
            return np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
        edges = [np.column_stack([xs, np.full_like(xs, ys[0])]), np.column_stack([xs, np.full_like(xs, ys[-1])]),
                 np.column_stack([np.full_like(ys, xs[0]), ys]), np.column_stack([np.full_like(ys, xs[-1]), ys])]
        return np.unique(np.concatenate(edges), axis=0)

    def outline(self, pose: Sequence[float]) -> np.ndarray:
        """Body rectangle corners at a pose, (4, 2) world (for plots)."""
        x0, x1, y0, y1 = self.body_rect()
        return transform(np.asarray(pose, float)[None], np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))[0]

    def wheel_centres(self, poses: np.ndarray) -> np.ndarray:
        """(N, 4, 2) world wheel contact centres at poses."""
        return transform(np.atleast_2d(poses), self.wheel_offsets())


def _axis(length: float, spacing: float) -> np.ndarray:
    n = max(2, int(math.ceil(length / spacing)) + 1)
    h = length / 2 - _INSET
    return np.linspace(-h, h, n)


def transform(poses: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Vehicle-frame points (K, 2) at poses (N, 3) -> world (N, K, 2)."""
    poses = np.asarray(poses, dtype=np.float64)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + c * local[None, :, 0] - s * local[None, :, 1]
    y = poses[:, 1:2] + s * local[None, :, 0] + c * local[None, :, 1]
    return np.stack([x, y], axis=-1)


# ---------------------------------------------------------------------- collision
class CollisionChecker:
    """Wheel- or body-level footprint checks of poses and motions on a grid map."""

    def __init__(self, grid: GridMap, vehicle: Vehicle | None = None, collision: str = "wheel") -> None:
        if collision not in COLLISION_MODES:
            raise RoadtwinError(f"unknown collision level {collision!r} (known: {', '.join(COLLISION_MODES)})")
        self.grid, self.vehicle, self.collision = grid, vehicle or Vehicle(), collision
        res = grid.resolution
        self.step = res / 2
        tires, self.wheel_of_point = self.vehicle.tire_points(self.step)
        self.tire_local = tires
        body = np.concatenate([self.vehicle.body_points(res / 1.5, False),   # every cell inside holds one
                               self.vehicle.body_points(self.step, True), tires])
        self.motion_local = tires if collision == "wheel" else body
        # The same motion samples at both levels (the whole vehicle's reach), so a body-level
        # check, whose points include the tires', is never less strict than a wheel-level one.
        self.reach = float(np.linalg.norm(body, axis=1).max())
        blocked = grid.defect | ~grid.drivable
        self._blocked = np.pad(blocked, 1, constant_values=True)  # outside the map is blocked
        self._x0, self._y0 = grid.origin
        self._res = res
        self._discs = self._disc_cover()
        self._disc_centres = np.array([d[0] for d in self._discs])
        self._disc_limits = np.array([d[1] for d in self._discs]) + math.sqrt(2) * res
        self._clear = None  # distance field to the nearest blocked cell, built on first use

    def _disc_cover(self) -> list[tuple[np.ndarray, float, np.ndarray]]:
        """Group the motion points into a few discs (centre, radius, points): per tire, or per
        quarter of the body's length."""
        pts = self.motion_local
        if self.collision == "wheel":
            labels = self.wheel_of_point
        else:
            x0, x1, _, _ = self.vehicle.body_rect()
            labels = np.clip(((pts[:, 0] - x0) / (x1 - x0) * 4).astype(int), 0, 3)
        out = []
        for k in np.unique(labels):
            p = pts[labels == k]
            c = 0.5 * (p.min(axis=0) + p.max(axis=0))
            out.append((c, float(np.linalg.norm(p - c, axis=1).max()), p))
        return out

    # -- cells
    def blocked_at(self, pts: np.ndarray) -> np.ndarray:
        """Whether world points fall on a blocked cell (defect, off the lanes or off the map)."""
        ix, iy = self._cells(pts)
        return self._blocked[iy, ix]

    def _cells(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Indices into the padded maps (clamped to the blocked border)."""
        ny, nx = self._blocked.shape
        ix = np.floor((pts[..., 0] - self._x0) / self._res).astype(np.int64) + 1
        iy = np.floor((pts[..., 1] - self._y0) / self._res).astype(np.int64) + 1
        return np.minimum(np.maximum(ix, 0), nx - 1), np.minimum(np.maximum(iy, 0), ny - 1)

    def free(self, poses: np.ndarray) -> np.ndarray:
        """(N,) whether each pose's footprint is collision-free.

        Exactly "no sample point on a blocked cell". Shortcut with the same answer: a disc of
        radius r around some of the points whose centre lies in a cell more than r + sqrt(2)
        cells from every blocked cell centre cannot have any of those points on a blocked cell
        (a point in a cell is within res/sqrt(2) of its centre), so only the points of discs
        that fail this test are looked up.
        """
        poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
        if len(poses) == 0:
            return np.zeros(0, bool)
        if self._clear is None:
            from scipy import ndimage

            self._clear = ndimage.distance_transform_edt(~self._blocked) * self._res
        free = np.ones(len(poses), bool)
        ix, iy = self._cells(transform(poses, self._disc_centres))
        doubtful = self._clear[iy, ix] <= self._disc_limits  # (N, discs)
        for k, (_, _, pts) in enumerate(self._discs):
            doubt = np.flatnonzero(free & doubtful[:, k])
            if len(doubt):
                free[doubt] = ~self.blocked_at(transform(poses[doubt], pts)).any(axis=1)
        return free

    # -- motions
    def densify(self, poses: np.ndarray) -> np.ndarray:
        """The poses with the motion between consecutive ones sampled (first pose included)."""
        p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
        if len(p) < 2:
            return p.copy()
        samples, _ = self.densify_pairs(p[:-1], p[1:])
        return np.concatenate([p[:1], samples])

    def densify_pairs(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Samples of the motions a[i] -> b[i] (a[i] excluded, b[i] included) and their pair index.

        Each motion gets n = max(1, ceil(distance / step), ceil(|yaw change| * reach / step))
        equal steps, so no footprint point moves more than ``step`` (half a cell) per sample.
        """
        d = b - a
        dyaw = wrap_angle(d[:, 2])
        dist = np.hypot(d[:, 0], d[:, 1])
        n = np.maximum(np.maximum(np.ceil(dist / self.step - 1e-9), np.ceil(np.abs(dyaw) * self.reach / self.step - 1e-9)),
                       1).astype(np.int64)
        seg = np.repeat(np.arange(len(d)), n)
        t = (np.arange(len(seg)) - np.repeat(np.cumsum(n) - n, n) + 1) / n[seg]
        out = np.empty((len(seg), 3))
        out[:, 0] = a[seg, 0] + t * d[seg, 0]
        out[:, 1] = a[seg, 1] + t * d[seg, 1]
        out[:, 2] = a[seg, 2] + t * dyaw[seg]
        return out, seg

    def chains_free(self, chains) -> np.ndarray:
        """(C,) for each chain of poses, whether the motion after its first pose is free.

        The first pose of each chain is where a planner already is (checked before); every
        sample after it, up to and including the last pose, is checked. ``chains`` is a list of
        (M_i, 3) arrays or one (C, M, 3) array; all of them go through numpy in one batch.
        """
        if isinstance(chains, np.ndarray) and chains.ndim == 3:
            c, m = chains.shape[:2]
            if c == 0 or m < 2:
                return np.ones(c, bool)
            a = chains[:, :-1].reshape(-1, 3)
            b = chains[:, 1:].reshape(-1, 3)
            owner = np.repeat(np.arange(c), m - 1)
        else:
            c = len(chains)
            chains = [np.asarray(x, dtype=np.float64) for x in chains]
            keep = [x for x in chains if len(x) > 1]
            if not keep:
                return np.ones(c, bool)
            a = np.concatenate([x[:-1] for x in keep])
            b = np.concatenate([x[1:] for x in keep])
            owner = np.repeat(np.arange(c), [max(len(x) - 1, 0) for x in chains])
        samples, pair = self.densify_pairs(a, b)
        hit = ~self.free(samples)
        return np.bincount(owner[pair], weights=hit, minlength=c) == 0

    def footprint_offsets(self, samples: np.ndarray) -> np.ndarray:
        """Cell offsets (dx, dy) hit by the motion footprint of ``samples`` (poses relative to a
        cell centre). A point within 1e-9 of a cell border counts for both cells, so a map
        dilated with these offsets is never less strict than checking the same poses in world
        coordinates (where rounding may put such a point on either side)."""
        pts = transform(samples, self.motion_local).reshape(-1, 2) / self._res + 0.5
        lo = np.floor(pts - 1e-9).astype(np.int64)
        hi = np.floor(pts + 1e-9).astype(np.int64)
        cand = np.concatenate([lo, hi, np.column_stack([lo[:, 0], hi[:, 1]]), np.column_stack([hi[:, 0], lo[:, 1]])])
        return np.unique(cand, axis=0)

    def motion_free_map(self, samples: np.ndarray) -> np.ndarray:
        """(ny, nx) map: True where the motion ``samples`` (poses relative to a cell centre),
        started from that cell's centre, hits no blocked cell (conservative, see above)."""
        off = self.footprint_offsets(samples)
        ny, nx = self.grid.shape
        pad = int(np.abs(off).max()) + 1
        b = np.pad(self._blocked[1:-1, 1:-1], pad, constant_values=True)
        free = np.ones((ny, nx), bool)
        for ox, oy in off:
            free &= ~b[pad + oy:pad + oy + ny, pad + ox:pad + ox + nx]
        return free

    def path_free(self, poses: np.ndarray) -> bool:
        poses = np.atleast_2d(poses)
        return bool(self.free(poses[:1])[0] and self.chains_free([poses])[0])

    # -- explanations
    def explain(self, pose: Sequence[float]) -> str:
        """Why a single pose collides ('' if it does not), naming the wheel and the defect."""
        g = self.grid
        pose = np.asarray(pose, dtype=np.float64)
        pts = transform(pose[None], self.tire_local)[0]
        ix, iy = g.world_to_cell(pts)
        inside = g.inside(ix, iy)
        for w in range(4):
            mine = self.wheel_of_point == w
            on_map = inside[mine]
            cx, cy = ix[mine][on_map], iy[mine][on_map]
            if not on_map.all() or not g.drivable[cy, cx].all():
                return f"its {WHEEL_NAMES[w]} wheel is off the drivable lanes"
            d = g.defect_index[cy, cx]
            if (d >= 0).any():
                k = int(d[d >= 0][0])
                return f"its {WHEEL_NAMES[w]} wheel is inside defect {g.defect_name(k)} ({g.defect_types[k]})"
        if self.collision == "body":
            pts = transform(pose[None], self.motion_local)[0]
            ix, iy = g.world_to_cell(pts)
            inside = g.inside(ix, iy)
            if not inside.all() or not g.drivable[iy[inside], ix[inside]].all():
                return "its body leaves the drivable lanes (body-level collision)"
            d = g.defect_index[iy, ix]
            if (d >= 0).any():
                k = int(d[d >= 0][0])
                return f"its body covers defect {g.defect_name(k)} ({g.defect_types[k]}) (body-level collision)"
        return ""


# ---------------------------------------------------------------------- geodesics
def drivable_distance(grid: GridMap, xy: Sequence[float], mask: np.ndarray | None = None,
                      predecessors: bool = False):
    """8-connected shortest distance (m) over ``mask`` (default: drivable) from the cell of ``xy``
    to every cell (+inf where unreachable); with ``predecessors`` also the predecessor array."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    mask = grid.drivable if mask is None else mask
    ny, nx = mask.shape
    ix, iy = grid.world_to_cell(np.asarray(xy, dtype=np.float64)[:2])
    dist = np.full(mask.shape, np.inf)
    pred = np.full(mask.shape, -1, np.int64)
    if not (grid.inside(ix, iy) and mask[iy, ix]):
        return (dist, pred) if predecessors else dist
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(int(mask.sum()))
    rows, cols, w = [], [], []
    r = grid.resolution
    for dy, dx, cost in ((0, 1, r), (1, 0, r), (1, 1, r * math.sqrt(2)), (1, -1, r * math.sqrt(2))):
        y0, y1 = max(0, -dy), ny - max(0, dy)
        x0, x1 = max(0, -dx), nx - max(0, dx)
        a = index[y0:y1, x0:x1]
        b = index[y0 + dy:y1 + dy, x0 + dx:x1 + dx]
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        w.append(np.full(int(ok.sum()), cost))
    n = int(mask.sum())
    graph = csr_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    d, p = dijkstra(graph, directed=False, indices=int(index[iy, ix]), return_predecessors=True)
    dist[mask] = d
    if predecessors:
        cells = np.flatnonzero(mask.ravel())
        pred[mask] = np.where(p >= 0, cells[np.maximum(p, 0)], -1)
        return dist, pred
    return dist


def segment_drivable(grid: GridMap, a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether the straight segment a-b stays on drivable cells (sampled every quarter cell)."""
    a, b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / (grid.resolution / 4))) + 1)
    pts = a + np.linspace(0, 1, n)[:, None] * (b - a)
    return bool(grid.sample(grid.drivable, pts, False).all())


def reference_path(grid: GridMap, start: Sequence[float], goal: Sequence[float]) -> np.ndarray:
    """The paper's reference ("the road midline"): the shortest drivable path start -> goal,
    defects ignored. The straight line when it stays on the lanes; otherwise the 8-connected
    geodesic, string-pulled (greedy line of sight) so it is not 8% too long on diagonals."""
    a, b = np.asarray(start, float)[:2], np.asarray(goal, float)[:2]
    if segment_drivable(grid, a, b):
        return np.array([a, b])
    dist, pred = drivable_distance(grid, a, predecessors=True)
    gx, gy = grid.world_to_cell(b)
    if not (grid.inside(gx, gy) and np.isfinite(dist[gy, gx])):
        raise RoadtwinError("goal is unreachable: no drivable connection from the start")
    ny, nx = grid.shape
    cells = [int(gy * nx + gx)]
    flat_pred = pred.ravel()
    while flat_pred[cells[-1]] >= 0:
        cells.append(int(flat_pred[cells[-1]]))
    cells = cells[::-1]
    pts = grid.cell_to_world(np.array(cells) % nx, np.array(cells) // nx)
    pts = np.concatenate([[a], pts[1:-1], [b]]) if len(pts) > 2 else np.array([a, b])
    out = [pts[0]]
    i = 0
    while i < len(pts) - 1:
        j = i + 1
        while j + 1 < len(pts) and segment_drivable(grid, pts[i], pts[j + 1]):
            j += 1
        out.append(pts[j])
        i = j
    return np.array(out)


def reference_frame(grid: GridMap, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per drivable cell, the distance (m) to a reference polyline (the route's midline) and the
    direction (rad) of its nearest segment; NaN elsewhere."""
    ref = np.asarray(reference, dtype=np.float64)[:, :2]
    dist = np.full(grid.shape, np.nan)
    head = np.full(grid.shape, np.nan)
    if len(ref) < 2:
        return dist, head
    a, seg = ref[:-1], np.diff(ref, axis=0)
    length2 = np.maximum((seg ** 2).sum(axis=1), 1e-12)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    iy, ix = np.nonzero(grid.drivable)
    pts = grid.cell_to_world(ix, iy)
    best = np.full(len(pts), np.inf)
    which = np.zeros(len(pts), np.int64)
    for k in range(len(seg)):
        t = np.clip(((pts - a[k]) @ seg[k]) / length2[k], 0.0, 1.0)
        d = ((a[k] + t[:, None] * seg[k] - pts) ** 2).sum(axis=1)
        closer = d < best
        best[closer] = d[closer]
        which[closer] = k
    dist[iy, ix] = np.sqrt(best)
    head[iy, ix] = heading[which]
    return dist, head


def lane_headings(grid: GridMap, reference: np.ndarray) -> np.ndarray:
    """Per drivable cell, the direction (rad) of the nearest segment of a reference polyline
    (the route's midline); NaN elsewhere. Grid planners keep the footprint at this heading."""
    return reference_frame(grid, reference)[1]


def polyline_length(xy: np.ndarray) -> float:
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


# ---------------------------------------------------------------------- metrics
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


def path_metrics(grid: GridMap, poses: np.ndarray, vehicle: Vehicle | None = None, collision: str = "wheel",
                 reference_length: float | None = None) -> PathMetrics:
    """The paper's metrics (see the module docstring) of a path; ``collision`` picks the level
    that ``collision_free`` is judged at."""
    vehicle = vehicle or Vehicle()
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    length, turn = heading_changes(poses)
    if reference_length is None:
        reference_length = polyline_length(reference_path(grid, poses[0], poses[-1]))
    dev = 100.0 * (length / reference_length - 1.0) if reference_length > 1e-9 else 0.0
    wheel = CollisionChecker(grid, vehicle, "wheel")
    body = CollisionChecker(grid, vehicle, "body")
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
    clear = grid.clearance(vehicle.wheel_centres(travel))
    clear_all = grid.clearance(vehicle.wheel_centres(dense))
    return PathMetrics(
        length_m=length, reference_length_m=float(reference_length), deviation_pct=float(dev),
        total_turn_rad=turn, smoothness_rad_per_m=turn / length if length > 1e-9 else 0.0,
        mean_clearance_m=float(clear.mean()), min_clearance_m=float(min(clear.min(), clear_all.min())),
        wheel_in_defect=bool(hit_ids), defects_under_wheels=hit_ids, body_over_defect=body_hit,
        off_road=bool(off.any()), collision_free=checker.path_free(poses))


# ---------------------------------------------------------------------- planning
@dataclass
class PlanResult:
    planner: str
    collision: str
    poses: np.ndarray                 # (N, 3)
    z: np.ndarray                     # (N,) road height under each pose
    metrics: PathMetrics
    time_s: float
    params: dict[str, Any]
    seed: int
    start: tuple[float, float, float]
    goal: tuple[float, float, float]

    def as_dict(self) -> dict[str, Any]:
        return {"planner": self.planner, "collision": self.collision, "seed": self.seed,
                "start": list(self.start), "goal": list(self.goal), "time_s": round(self.time_s, 4),
                "poses": len(self.poses), "params": self.params, "metrics": self.metrics.as_dict()}


@dataclass
class PlanFailure:
    planner: str
    collision: str
    reason: str
    time_s: float


def parse_pose(text: str, what: str) -> tuple[float, float, float]:
    """'x,y,yaw' (metres, metres, radians) -> a finite pose, or a RoadtwinError naming ``what``."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise RoadtwinError(f"{what} must be X,Y,YAW (metres, metres, radians), got {text!r}")
    return values[0], values[1], values[2]


def check_endpoint(checker: CollisionChecker, pose: Sequence[float], what: str) -> None:
    """Refuse a start/goal that is off the lanes or puts a wheel in a defect (wheel level), or,
    for body-level planning, whose body collides."""
    why = CollisionChecker(checker.grid, checker.vehicle, "wheel").explain(pose) or checker.explain(pose)
    if why:
        x, y, yaw = pose
        raise RoadtwinError(f"{what} ({x:g}, {y:g}, {yaw:g}) is not a valid pose: {why}")


def plan_path(grid: GridMap, planner: Any, start: Sequence[float], goal: Sequence[float], *,
              vehicle: Vehicle | None = None, collision: str = "wheel", params: dict[str, Any] | None = None,
              seed: int = 0, reference_length: float | None = None, pm=None) -> PlanResult:
    """Run one planner (a registered name or an object) and measure its path."""
    from .params import make_params

    if isinstance(planner, str):
        from .plugins import get_plugin_manager

        planner = (pm or get_plugin_manager()).get("planners", planner)
    vehicle = vehicle or Vehicle()
    checker = CollisionChecker(grid, vehicle, collision)
    start = tuple(float(v) for v in start)
    goal = tuple(float(v) for v in goal)
    check_endpoint(checker, start, "start")
    check_endpoint(checker, goal, "goal")
    if reference_length is None:
        reference_length = polyline_length(reference_path(grid, start, goal))
    p = make_params(planner.Params, dict(params or {}), f"planner {planner.name}")
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    poses = planner.plan(grid, start, goal, vehicle, collision, p, rng)
    dt = time.perf_counter() - t0
    if poses is None or len(poses) == 0:
        hint = ("the body may not fit past the defects; try --collision wheel or another planner"
                if collision == "body" else "defects may block the road for the wheels, or the search budget "
                "ran out; try another planner")
        raise RoadtwinError(f"planner {planner.name}: found no {collision}-level collision-free path from "
                            f"start to goal ({hint})")
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(poses).all():
        raise RoadtwinError(f"planner {planner.name}: returned a path with NaN or inf poses")
    for end, want, what in ((poses[0], start, "start"), (poses[-1], goal, "goal")):
        if np.hypot(*(end[:2] - np.array(want[:2]))) > 1e-6 or abs(wrap_angle(end[2] - want[2])) > 1e-6:
            raise RoadtwinError(f"planner {planner.name}: its path does not end at the {what} pose")
    metrics = path_metrics(grid, poses, vehicle, collision, reference_length)
    return PlanResult(planner.name, collision, poses, grid.road_height(poses[:, :2]), metrics, dt,
                      asdict(p), seed, start, goal)


# ---------------------------------------------------------------------- outputs
def write_path_csv(path: Path, result: PlanResult) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["x", "y", "z", "yaw"])
        for (x, y, yaw), z in zip(result.poses, result.z):
            w.writerow([f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", f"{float(wrap_angle(yaw)):.6f}"])
    return path


def write_metrics_json(path: Path, result: PlanResult, extra: dict[str, Any] | None = None) -> Path:
    data = result.as_dict()
    data.update(extra or {})
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    return path


COMPARISON_COLUMNS = ("planner", "collision", "status", "length_m", "reference_length_m", "deviation_pct",
                      "smoothness_rad_per_m", "mean_clearance_m", "min_clearance_m", "wheel_in_defect",
                      "off_road", "time_s")


def comparison_rows(results: Iterable[PlanResult | PlanFailure]) -> list[dict[str, Any]]:
    rows = []
    for r in results:
        if isinstance(r, PlanFailure):
            rows.append({"planner": r.planner, "collision": r.collision, "status": f"failed: {r.reason}",
                         "time_s": round(r.time_s, 3)})
            continue
        m = r.metrics
        rows.append({"planner": r.planner, "collision": r.collision, "status": "ok",
                     "length_m": round(m.length_m, 3), "reference_length_m": round(m.reference_length_m, 3),
                     "deviation_pct": round(m.deviation_pct, 3), "smoothness_rad_per_m": round(m.smoothness_rad_per_m, 4),
                     "mean_clearance_m": round(m.mean_clearance_m, 3), "min_clearance_m": round(m.min_clearance_m, 3),
                     "wheel_in_defect": m.wheel_in_defect, "off_road": m.off_road, "time_s": round(r.time_s, 3)})
    return rows


def write_comparison_csv(path: Path, results: Iterable[PlanResult | PlanFailure]) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COMPARISON_COLUMNS)
        w.writeheader()
        for row in comparison_rows(results):
            w.writerow(row)
    return path


_COLOURS = {"astar": "tab:blue", "rrtstar": "tab:orange", "lattice": "tab:green", "hybrid_astar": "tab:purple"}


def _draw_grid(ax, grid: GridMap) -> None:
    import matplotlib.colors as mcolors

    img = np.where(grid.drivable, 0.85, 1.0)
    ax.imshow(img, origin="lower", extent=grid.extent, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    depth = np.ma.masked_where(~grid.defect, grid.depth * 100)
    vmax = max(1.0, float(depth.max()) if grid.defect.any() else 1.0)
    im = ax.imshow(depth, origin="lower", extent=grid.extent, cmap="Reds",
                   norm=mcolors.Normalize(0, vmax), interpolation="nearest")
    if grid.defect.any():  # outline the defects: small ones are only a few cells
        x0, x1, y0, y1 = grid.extent
        ny, nx = grid.shape
        xs = np.linspace(x0 + grid.resolution / 2, x1 - grid.resolution / 2, nx)
        ys = np.linspace(y0 + grid.resolution / 2, y1 - grid.resolution / 2, ny)
        ax.contour(xs, ys, grid.defect.astype(float), levels=[0.5], colors="darkred", linewidths=0.8)
    return im


def _draw_result(ax, result: PlanResult, vehicle: Vehicle, colour: str, label: str, tracks: bool = True) -> None:
    p = result.poses
    ax.plot(p[:, 0], p[:, 1], "-", color=colour, lw=1.6, label=label, zorder=4)
    if tracks:
        travel = resample_by_length(p, 0.1)
        w = vehicle.wheel_centres(travel)
        for k in range(4):
            ax.plot(w[:, k, 0], w[:, k, 1], ":", color=colour, lw=0.8, zorder=3)
        s = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(travel[:, :2], axis=0).T))])
        for target in np.arange(0, s[-1] + 1e-9, 6.0):
            pose = travel[int(np.searchsorted(s, target).clip(0, len(travel) - 1))]
            c = vehicle.outline(pose)
            ax.fill(c[:, 0], c[:, 1], fill=False, ec=colour, lw=0.5, alpha=0.6, zorder=3)


def write_plot(path: Path, grid: GridMap, results: Sequence[PlanResult], vehicle: Vehicle | None = None,
               title: str = "") -> Path:
    """Grid, defects (by depth), each path with its wheel tracks and a body outline every 6 m.
    One result: one panel; several: one panel per result, stacked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    vehicle = vehicle or Vehicle()
    x0, x1, y0, y1 = grid.extent
    if results:  # zoom to the paths (and their wheels) plus a margin, within the map
        pts = np.concatenate([np.concatenate([r.poses[:, :2], vehicle.wheel_centres(r.poses).reshape(-1, 2)])
                              for r in results])
        lo, hi = pts.min(axis=0) - 8.0, pts.max(axis=0) + 8.0
        x0, x1, y0, y1 = max(x0, lo[0]), min(x1, hi[0]), max(y0, lo[1]), min(y1, hi[1])
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    n = max(1, len(results))
    width = 13.0
    panel_h = float(np.clip(width * aspect, 1.6, 9.0)) + 0.7
    fig, axes = plt.subplots(n, 1, figsize=(width, panel_h * n + 0.3), squeeze=False)
    im = None
    for ax, r in zip(axes[:, 0], results or [None]):
        im = _draw_grid(ax, grid)
        if r is not None:
            colour = _COLOURS.get(r.planner, "tab:cyan")
            _draw_result(ax, r, vehicle, colour, r.planner)
            ax.plot(*r.start[:2], "o", color="k", ms=4, zorder=5)
            ax.plot(*r.goal[:2], "*", color="k", ms=8, zorder=5)
            m = r.metrics
            ax.set_title(f"{r.planner} ({r.collision}-level): length {m.length_m:.2f} m, deviation "
                         f"{m.deviation_pct:.2f} %, smoothness {m.smoothness_rad_per_m:.3f} rad/m, clearance "
                         f"{m.mean_clearance_m:.2f} m (min {m.min_clearance_m:.2f})"
                         + (", WHEEL IN DEFECT" if m.wheel_in_defect else ""), fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    if title:
        fig.suptitle(title, fontsize=10)
    if im is not None and grid.defect.any():
        fig.colorbar(im, ax=axes[:, 0].tolist(), label="defect depth (cm)", shrink=0.8, pad=0.01)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def write_path_layer(path: Path, town_ref: str, root_name: str, results: Sequence[PlanResult], grid: GridMap,
                     vehicle: Vehicle | None = None, lift_m: float = 0.05) -> Path:
    """A USD layer (Z up, metres, defaultPrim) that sublayers the town stage (``town_ref``,
    relative to the layer or absolute) and adds, per result, an Xform
    ``/<root>/Plans/<planner>_<collision>`` carrying the metrics as ``roadtwin:plan:*``
    attributes, with two linear ``BasisCurves``: ``Path`` (the rear-axle path) and
    ``WheelTracks`` (the four wheel contact centres). z = road height + ``lift_m``, so the curves
    are drawn on the road rather than inside it."""
    from pxr import Sdf, UsdGeom

    from .usd.stage import new_stage, set_attrs, set_kind

    vehicle = vehicle or Vehicle()
    path = Path(path)
    stage = new_stage(path, root_name, "roadtwin planned path(s) over " + town_ref)
    stage.GetRootLayer().subLayerPaths = [town_ref]
    stage.OverridePrim(Sdf.Path(f"/{root_name}"))
    plans = UsdGeom.Xform.Define(stage, f"/{root_name}/Plans")
    set_kind(plans.GetPrim(), "group")
    for r in results:
        name = f"{r.planner}_{r.collision}"
        group = UsdGeom.Xform.Define(stage, f"/{root_name}/Plans/{name}").GetPrim()
        m = r.metrics
        set_attrs(group, "roadtwin:plan", {
            "planner": r.planner, "collision": r.collision, "lengthM": m.length_m, "deviationPct": m.deviation_pct,
            "smoothnessRadPerM": m.smoothness_rad_per_m, "meanClearanceM": _finite(m.mean_clearance_m),
            "minClearanceM": _finite(m.min_clearance_m), "wheelInDefect": m.wheel_in_defect, "seed": int(r.seed),
            "liftM": float(lift_m)})
        z = np.nan_to_num(np.asarray(r.z, dtype=np.float64), nan=0.0)
        curve = UsdGeom.BasisCurves.Define(stage, f"/{root_name}/Plans/{name}/Path")
        _set_curves(curve, [np.column_stack([r.poses[:, :2], z + lift_m])], 0.1, _rgb(r.planner))
        travel = resample_by_length(r.poses, 0.25)
        w = vehicle.wheel_centres(travel)
        tracks = []
        for k in range(4):
            wz = np.nan_to_num(grid.road_height(w[:, k]), nan=0.0)
            tracks.append(np.column_stack([w[:, k], wz + lift_m]))
        _set_curves(UsdGeom.BasisCurves.Define(stage, f"/{root_name}/Plans/{name}/WheelTracks"), tracks, 0.04,
                    tuple(0.5 * c for c in _rgb(r.planner)))
    stage.GetRootLayer().Save()
    return path


def _finite(v: float) -> float:
    return float(v) if math.isfinite(v) else -1.0


def _rgb(planner: str) -> tuple[float, float, float]:
    import matplotlib.colors as mcolors

    return tuple(float(c) for c in mcolors.to_rgb(_COLOURS.get(planner, "tab:cyan")))


def _set_curves(curve, polylines: list[np.ndarray], width: float, rgb) -> None:
    from pxr import UsdGeom, Vt

    pts = np.concatenate(polylines).astype(np.float32)
    curve.CreateTypeAttr(UsdGeom.Tokens.linear)
    curve.CreateCurveVertexCountsAttr(Vt.IntArray([len(p) for p in polylines]))
    curve.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    curve.CreateWidthsAttr(Vt.FloatArray([width]))
    curve.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    curve.CreateDisplayColorAttr(Vt.Vec3fArray([rgb]))
    lo, hi = pts.min(axis=0) - width / 2, pts.max(axis=0) + width / 2
    curve.CreateExtentAttr(Vt.Vec3fArray([tuple(lo.tolist()), tuple(hi.tolist())]))


# ---------------------------------------------------------------------- a whole run
@dataclass
class PlanRun:
    outdir: Path
    town: Path
    grid: GridMap
    results: list[PlanResult | PlanFailure] = field(default_factory=list)
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    goal: tuple[float, float, float] = (0.0, 0.0, 0.0)
    composed: bool = False
    decisions: list = field(default_factory=list)   # bypass / cross per defect on the route (--sweep)


def plan_stage(stage: str | Path, outdir: str | Path, *, planners: Sequence[str] | None = None,
               start: str | Sequence[float] | None = None, goal: str | Sequence[float] | None = None,
               collision: str = "wheel", resolution: float = 0.2, seed: int = 0,
               vehicle: Vehicle | None = None, pm=None, validate: bool = True,
               sweep: str | Path | None = None, max_g: float = 1.0,
               planner_params: dict[str, Any] | None = None) -> PlanRun:
    """``roadtwin plan``: grid maps of a composed town (or a layout, composed first into
    ``OUTDIR/town``), one or more planners, and their outputs, written atomically to ``outdir``.

    ``planners=None`` runs every registered planner, each into its own subfolder, plus
    ``comparison.csv``, ``comparison.png`` and ``paths.usda``; one planner writes straight into
    ``outdir``: ``path.csv``, ``path.usda``, ``metrics.json``, ``plot.png``.
    """
    from .atomic import atomic_output_dir
    from .grid import rasterize_scene
    from .plugins import get_plugin_manager
    from .usd.town_reader import load_town

    pm = pm or get_plugin_manager()
    vehicle = vehicle or Vehicle()
    if collision not in COLLISION_MODES:
        raise RoadtwinError(f"unknown collision level {collision!r} (known: {', '.join(COLLISION_MODES)})")
    if not (math.isfinite(resolution) and resolution > 0):
        raise RoadtwinError(f"--resolution must be a positive number of metres, got {resolution}")
    if planners is None:
        names = list(pm.registry("planners"))  # registration order (the built-ins: the paper's order)
        if not names:
            raise RoadtwinError("no planners are registered (is the roadtwin planners plugin installed?)")
    else:
        names = list(planners)
    impls = {n: pm.get("planners", n) for n in names}  # unknown planner: error before any work
    single = planners is not None and len(names) == 1

    stage = Path(stage)
    if stage.is_dir():
        stage = stage / "town.usda"
    outdir = Path(outdir).resolve()
    if stage.resolve().is_relative_to(outdir):
        raise RoadtwinError(f"{stage}: lies inside the output directory {outdir}, which plan replaces")
    scene = load_town(stage)
    composed = not scene.colliders
    if composed and not scene.roads:
        raise RoadtwinError(f"{stage}: neither a composed town (no collision meshes) nor a layout (no road segments)")
    if sweep is not None:
        from .route_decisions import load_recommendations

        load_recommendations(sweep)  # a bad sweep folder fails before any work
        if not (math.isfinite(max_g) and max_g > 0):
            raise RoadtwinError(f"--max-g must be a positive number, got {max_g}")
    start = _pose_arg(start, scene.metadata, "planStart", "start", stage)
    goal = _pose_arg(goal, scene.metadata, "planGoal", "goal", stage)

    with atomic_output_dir(outdir) as tmp:
        if composed:
            from .compose import compose

            town = compose(stage, tmp / "town", pm=pm).town
            scene = load_town(town)
            town_ref = lambda d: os.path.relpath(tmp / "town" / "town.usda", d).replace(os.sep, "/")  # noqa: E731
        else:
            town = stage.resolve()
            town_ref = lambda d: str(town)  # noqa: E731
        grid = rasterize_scene(scene, resolution)
        base = CollisionChecker(grid, vehicle, collision)
        check_endpoint(base, start, "start")
        check_endpoint(base, goal, "goal")
        ref = reference_path(grid, start, goal)  # raises when the goal is not connected
        ref_len = polyline_length(ref)
        run = PlanRun(outdir, outdir / "town" / "town.usda" if composed else town, grid, [], start, goal, composed)
        if sweep is not None:
            from .route_decisions import decide, write_decisions

            run.decisions = decide(grid, ref, vehicle, sweep, max_g)
            write_decisions(tmp, run.decisions)
        for name in names:
            t0 = time.perf_counter()
            try:
                r = plan_path(grid, impls[name], start, goal, vehicle=vehicle, collision=collision, seed=seed,
                              reference_length=ref_len, pm=pm, params=planner_params)
            except RoadtwinError as exc:
                if single:
                    raise
                run.results.append(PlanFailure(name, collision, str(exc).split(": ", 1)[-1], time.perf_counter() - t0))
                continue
            run.results.append(r)
            d = tmp if single else tmp / name
            d.mkdir(exist_ok=True)
            write_path_csv(d / "path.csv", r)
            write_metrics_json(d / "metrics.json", r, {"stage": str(stage), "town": str(run.town),
                                                       "grid": grid.summary(), "vehicle": asdict(vehicle),
                                                       "reference_path": ref.tolist()})
            write_plot(d / "plot.png", grid, [r], vehicle, f"{stage.name}: {name}")
            write_path_layer(d / "path.usda", town_ref(d), scene.name, [r], grid, vehicle)
            if validate:
                _validate(d / "path.usda")
        ok = [r for r in run.results if isinstance(r, PlanResult)]
        if not ok:
            raise RoadtwinError("no planner found a path: " + "; ".join(f"{r.planner}: {r.reason}" for r in run.results))
        if not single:
            write_comparison_csv(tmp / "comparison.csv", run.results)
            write_plot(tmp / "comparison.png", grid, ok, vehicle, f"{stage.name}: {collision}-level collision")
            _write_paths_index(tmp / "paths.usda", scene.name, [f"./{r.planner}/path.usda" for r in ok])
            if validate:
                _validate(tmp / "paths.usda")
    return run


def _write_paths_index(path: Path, root_name: str, layers: list[str]) -> None:
    from pxr import Sdf

    from .usd.stage import new_stage

    stage = new_stage(path, root_name, "roadtwin: every planner's path over the town")
    stage.GetRootLayer().subLayerPaths = layers
    stage.OverridePrim(Sdf.Path(f"/{root_name}"))
    stage.GetRootLayer().Save()


def _validate(path: Path) -> None:
    from .usd.validate import validate_stage

    errors = [f for f in validate_stage(path) if f.severity == "Error"]
    if errors:
        raise RoadtwinError(f"{path.name} fails validation: {errors[0].validator}: {errors[0].message}")


def _pose_arg(value, metadata: dict, key: str, what: str, stage: Path) -> tuple[float, float, float]:
    if value is None:
        if key not in metadata:
            raise RoadtwinError(f"{stage}: no --{what} given and the stage has no roadtwin:layout:{key} default")
        return parse_pose(str(metadata[key]), f"{stage}: roadtwin:layout:{key}")
    if isinstance(value, str):
        return parse_pose(value, f"--{what}")
    v = [float(x) for x in value]
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise RoadtwinError(f"--{what} must be X,Y,YAW, got {value!r}")
    return v[0], v[1], v[2]
