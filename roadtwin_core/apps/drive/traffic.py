"""Other vehicles on the lanes (issue 20 item 1, optional): kinematic props that the cameras and
the LiDAR see, not obstacles the physics knows.

Each is a box (a car's length, width and height) driving a lane of the stage at a constant speed,
its heading the lane's, its bottom on the road (a ray cast down through the town at its centre),
stopping at the lane's end. Where vehicles go is fixed by the route and their number alone (no
random draw): the lanes nearest the route's middle, in turn, spread along each lane and kept
``clear_m`` away from the ego's start. The world draws them into every frame it renders (z-buffered
against the town, Lambert-shaded under a fixed sun, class ``vehicle`` and one instance id each)
and into every LiDAR cast, where they are at the sample's time (a LiDAR frame's end for all its
points, a camera's exposure middle for every motion-blur sub-frame: within 0.1 s and 8 ms of a
car's motion).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Traffic", "clear_of_ego", "place_traffic", "ray_boxes"]

CAR_SIZE_M = (4.5, 1.8, 1.5)           # length, width, height
PALETTE = ((0.55, 0.05, 0.05), (0.05, 0.12, 0.45), (0.7, 0.7, 0.72), (0.08, 0.08, 0.08), (0.9, 0.9, 0.88))
SUN = np.array([0.4, 0.3, 0.87]) / np.linalg.norm([0.4, 0.3, 0.87])


@dataclass
class Vehicle:
    lane: object                        # render.Lane
    s0: float                           # arc length on the lane at t = 0
    speed_mps: float
    colour: tuple


class Traffic:
    """The other vehicles; ``boxes(t)`` their oriented boxes at ``t`` (the ground under each from
    ``ground(xy) -> z``)."""

    def __init__(self, vehicles: list[Vehicle], ground, size=CAR_SIZE_M) -> None:
        self.vehicles, self.ground, self.size = vehicles, ground, np.asarray(size, np.float64)

    def __len__(self) -> int:
        return len(self.vehicles)

    def boxes(self, t: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """(centre, rotation (columns: forward, left, up), half extents) of each vehicle at ``t``."""
        out = []
        for v in self.vehicles:
            s = min(v.s0 + v.speed_mps * t, v.lane.length - self.size[0] / 2)
            xy = v.lane.at([s])[0]
            yaw = float(v.lane.heading([s])[0])
            z = float(self.ground(xy))
            c, sn = math.cos(yaw), math.sin(yaw)
            R = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
            out.append((np.array([xy[0], xy[1], z + self.size[2] / 2]), R, self.size / 2))
        return out


def place_traffic(n: int, lanes: list, route, speed_mps: float, ground, clear_m: float = 15.0,
                  spacing_m: float = 20.0) -> Traffic:
    """``n`` vehicles on the lanes nearest the route's middle, in turn, ``spacing_m`` apart about
    each lane's point nearest that middle (where the ego's sensors see them); one that would stand
    within ``clear_m`` of the ego's start moves on along its lane, ``spacing_m`` at a time."""
    mid = route.at(np.array([route.length / 2]))[0][0]
    start = route.at(np.array([0.0]))[0][0]

    def distance(lane) -> float:
        return float(np.min(np.linalg.norm(lane.points - mid, axis=1)))

    order = sorted((ln for ln in lanes if ln.length > 2 * CAR_SIZE_M[0]), key=lambda ln: (distance(ln), ln.id))
    vehicles: list[Vehicle] = []
    per_lane = -(-n // max(len(order), 1)) if order else 0
    for lane in order:
        s_mid = float(lane.cum[np.argmin(np.linalg.norm(lane.points - mid, axis=1))])   # its vertex nearest it
        for k in range(per_lane):
            want = s_mid + (k - (per_lane - 1) / 2) * spacing_m
            s0 = next((float(x) for x in want + spacing_m * np.arange(4)
                       if CAR_SIZE_M[0] <= x <= lane.length - CAR_SIZE_M[0]
                       and np.linalg.norm(lane.at([x])[0] - start) >= clear_m), None)
            if s0 is not None and len(vehicles) < n:
                vehicles.append(Vehicle(lane, s0, speed_mps, PALETTE[len(vehicles) % len(PALETTE)]))
    return Traffic(vehicles, ground)


def _ego_plan(route, profile, t_end: float | None, step_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Times and the ego's arc lengths at them along the route, from its speed profile (the
    plan the speed controller follows), to the route's end or ``t_end``."""
    t_knots, s_knots = [0.0], [0.0]
    for a, b, v in profile.pieces(route.length):
        t_knots.append(t_knots[-1] + (b - a) / v)
        s_knots.append(b)
    end = t_knots[-1] if t_end is None else min(t_end, t_knots[-1])
    t = np.arange(0.0, end + step_s / 2, step_s)
    return t, np.interp(t, t_knots, s_knots)


def _boxes_overlap(ca, ta, ha, cb, tb, hb) -> np.ndarray:
    """Whether oriented plan rectangles overlap (separating axes), elementwise over rows: centres
    (N,2), unit forward directions (N,2), half extents (length, width)."""
    na, nb = np.column_stack([-ta[:, 1], ta[:, 0]]), np.column_stack([-tb[:, 1], tb[:, 0]])
    d = cb - ca
    hit = np.ones(len(ca), bool)
    for u in (ta, na, tb, nb):
        ra = ha[0] * np.abs((ta * u).sum(1)) + ha[1] * np.abs((na * u).sum(1))
        rb = hb[0] * np.abs((tb * u).sum(1)) + hb[1] * np.abs((nb * u).sum(1))
        hit &= np.abs((d * u).sum(1)) <= ra + rb
    return hit


def clear_of_ego(traffic: Traffic, route, profile, body_m: tuple[float, float], t_end: float | None = None,
                 step_s: float = 0.05, margin_m: float = 0.5) -> tuple[Traffic, list[int]]:
    """The traffic without the vehicles whose box would come within ``margin_m`` of the ego's
    body (``body_m``: width, length) on its planned path: they are kinematic, they neither brake
    nor steer, so one in the ego's lane at another speed, or stopped at its lane's end on the
    route, would drive through the ego (the cameras inside it). Returns it and the indices left
    out."""
    t, s = _ego_plan(route, profile, t_end, step_s)
    p, tan = route.at(s)
    ego_half = np.array([body_m[1] / 2 + margin_m, body_m[0] / 2 + margin_m])
    car_half = traffic.size[:2] / 2
    kept, out = [], []
    for k, v in enumerate(traffic.vehicles):
        sv = np.minimum(v.s0 + v.speed_mps * t, v.lane.length - traffic.size[0] / 2)
        yaw = v.lane.heading(sv)
        hit = _boxes_overlap(p, tan, ego_half, v.lane.at(sv), np.column_stack([np.cos(yaw), np.sin(yaw)]), car_half)
        (out if hit.any() else kept).append(k)
    return Traffic([traffic.vehicles[k] for k in kept], traffic.ground, traffic.size), out


def ray_boxes(origins: np.ndarray, dirs: np.ndarray, boxes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest box hit along each unit ray (slab method): distance (inf: none), box index (-1) and
    the world normal of the face hit."""
    n = len(dirs)
    best = np.full(n, np.inf)
    which = np.full(n, -1, np.int64)
    normal = np.zeros((n, 3))
    for k, (centre, R, half) in enumerate(boxes):
        o = (origins - centre) @ R                 # box frame
        d = dirs @ R
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1, t2 = (-half - o) * inv, (half - o) * inv
        t_near = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf)
        t_far = np.nan_to_num(np.maximum(t1, t2), nan=np.inf)
        enter, leave = t_near.max(axis=1), t_far.min(axis=1)
        hit = (enter <= leave) & (enter > 0) & (enter < best)
        if not hit.any():
            continue
        axis = np.argmax(t_near[hit], axis=1)
        local = np.zeros((int(hit.sum()), 3))
        local[np.arange(len(axis)), axis] = -np.sign(d[hit][np.arange(len(axis)), axis])
        best[hit], which[hit], normal[hit] = enter[hit], k, local @ R.T
    return best, which, normal


def shade(normal: np.ndarray, colour) -> np.ndarray:
    """Linear RGB of a painted face under the fixed sun and a sky ambient."""
    lambert = np.clip(normal @ SUN, 0.0, 1.0)
    return (0.25 + 0.75 * lambert)[:, None] * np.asarray(colour, np.float32)[None, :]
