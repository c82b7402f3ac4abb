"""Wheel- or body-level collision of poses and motions on a grid map (see the package docstring)."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy import ndimage

from ..errors import RoadtwinError
from .grid import GridMap
from .footprint import WHEEL_NAMES, Footprint, transform, wrap_angle

COLLISION_MODES = ("wheel", "body")


class CollisionChecker:
    """Wheel- or body-level footprint checks of poses and motions on a grid map."""

    def __init__(self, grid: GridMap, footprint: Footprint, collision: str = "wheel") -> None:
        if collision not in COLLISION_MODES:
            raise RoadtwinError(f"unknown collision level {collision!r} (known: {', '.join(COLLISION_MODES)})")
        if not isinstance(footprint, Footprint):
            raise RoadtwinError("collision checks need a planning Footprint (VehicleParams.footprint()), "
                                f"got {type(footprint).__name__}")
        self.grid, self.footprint, self.collision = grid, footprint, collision
        res = grid.resolution
        self.step = res / 2
        tires, self.wheel_of_point = self.footprint.tire_points(self.step)
        self.tire_local = tires
        body = np.concatenate([self.footprint.body_points(res / 1.5, False),   # every cell inside holds one
                               self.footprint.body_points(self.step, True), tires])
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
            x0, x1, _, _ = self.footprint.body_rect()
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



def check_endpoint(checker: CollisionChecker, pose: Sequence[float], what: str) -> None:
    """Refuse a start/goal that is off the lanes or puts a wheel in a defect (wheel level), or,
    for body-level planning, whose body collides."""
    why = CollisionChecker(checker.grid, checker.footprint, "wheel").explain(pose) or checker.explain(pose)
    if why:
        x, y, yaw = pose
        raise RoadtwinError(f"{what} ({x:g}, {y:g}, {yaw:g}) is not a valid pose: {why}")

