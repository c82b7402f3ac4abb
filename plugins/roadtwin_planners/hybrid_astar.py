"""Hybrid A* (Dolgov et al.): A* over (x, y, heading) bins with kinematic-bicycle motions.

Each expansion drives ``step_m`` forward along a constant-curvature arc for each of
``steer_count`` steering angles spread over [-max steer, +max steer] of the vehicle
(curvature = tan(steer) / wheelbase, the paper's 3.0 m wheelbase), sampled every 0.1 m and
footprint-checked through the core's collision checker. States keep their exact continuous pose;
the closed set bins them by ``xy_resolution_m`` and ``heading_bins``. Cost = arc length
x (1 + ``steer_cost`` |steer|/max) + ``steer_change_cost`` |steer change|/max; heuristic =
max(Euclidean, drivable geodesic) to the goal. Within ``shot_distance_m`` of the goal a forward
Dubins path (turning radius = ``shot_radius_scale`` x the minimum one) to the exact goal pose is
tried every ``shot_every``-th expansion (the analytic expansion); forward motion only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import field
from roadtwin_core.planning import CollisionChecker, GridMap, PlannerOutput, wrap_angle

from ._search import Node, astar, heuristic_field

_SAMPLE_M = 0.1


def arc(pose: np.ndarray, kappa: float, length: float, ds: float = _SAMPLE_M) -> np.ndarray:
    """Poses along a constant-curvature arc from ``pose`` (excluded), about every ``ds``."""
    n = max(1, int(math.ceil(length / ds)))
    s = np.linspace(length / n, length, n)
    x, y, th = pose
    if abs(kappa) < 1e-9:
        return np.column_stack([x + s * math.cos(th), y + s * math.sin(th), np.full(n, th)])
    t = th + kappa * s
    return np.column_stack([x + (np.sin(t) - math.sin(th)) / kappa, y - (np.cos(t) - math.cos(th)) / kappa, t])


# ---------------------------------------------------------------------- Dubins (forward only)
def _mod2pi(a: float) -> float:
    return a % (2 * math.pi)


def dubins_words(q0, q1, rho: float) -> list[tuple[str, tuple[float, float, float]]]:
    """All feasible Dubins words (Shkel & Lumelsky) as (word, normalised segment lengths)."""
    dx, dy = q1[0] - q0[0], q1[1] - q0[1]
    d = math.hypot(dx, dy) / rho
    theta = _mod2pi(math.atan2(dy, dx)) if d > 0 else 0.0
    a, b = _mod2pi(q0[2] - theta), _mod2pi(q1[2] - theta)
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    cab, d2 = math.cos(a - b), d * d
    out = []
    p2 = 2 + d2 - 2 * cab + 2 * d * (sa - sb)
    if p2 >= 0:
        t1 = math.atan2(cb - ca, d + sa - sb)
        out.append(("LSL", (_mod2pi(t1 - a), math.sqrt(p2), _mod2pi(b - t1))))
    p2 = 2 + d2 - 2 * cab + 2 * d * (sb - sa)
    if p2 >= 0:
        t1 = math.atan2(ca - cb, d - sa + sb)
        out.append(("RSR", (_mod2pi(a - t1), math.sqrt(p2), _mod2pi(t1 - b))))
    p2 = -2 + d2 + 2 * cab + 2 * d * (sa + sb)
    if p2 >= 0:
        p = math.sqrt(p2)
        t0 = math.atan2(-ca - cb, d + sa + sb) - math.atan2(-2.0, p)
        out.append(("LSR", (_mod2pi(t0 - a), p, _mod2pi(t0 - _mod2pi(b)))))
    p2 = -2 + d2 + 2 * cab - 2 * d * (sa + sb)
    if p2 >= 0:
        p = math.sqrt(p2)
        t0 = math.atan2(ca + cb, d - sa - sb) - math.atan2(2.0, p)
        out.append(("RSL", (_mod2pi(a - t0), p, _mod2pi(b - t0))))
    t0 = (6 - d2 + 2 * cab + 2 * d * (sa - sb)) / 8
    if abs(t0) <= 1:
        p = _mod2pi(2 * math.pi - math.acos(t0))
        t = _mod2pi(a - math.atan2(ca - cb, d - sa + sb) + p / 2)
        out.append(("RLR", (t, p, _mod2pi(a - b - t + p))))
    t0 = (6 - d2 + 2 * cab + 2 * d * (sb - sa)) / 8
    if abs(t0) <= 1:
        p = _mod2pi(2 * math.pi - math.acos(t0))
        t = _mod2pi(-a - math.atan2(ca - cb, d + sa - sb) + p / 2)
        out.append(("LRL", (t, p, _mod2pi(_mod2pi(b) - a - t + p))))
    return out


def dubins_sample(q0, word: str, lengths, rho: float, ds: float = _SAMPLE_M) -> np.ndarray:
    """Poses along a Dubins word from q0 (excluded)."""
    pose = np.asarray(q0, dtype=np.float64)
    parts = []
    for kind, seg in zip(word, lengths):
        if seg * rho < 1e-9:
            continue
        kappa = {"L": 1.0 / rho, "R": -1.0 / rho, "S": 0.0}[kind]
        pts = arc(pose, kappa, seg * rho, ds)
        parts.append(pts)
        pose = pts[-1]
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def dubins_path(q0, q1, rho: float, ds: float = _SAMPLE_M) -> list[np.ndarray]:
    """Sampled Dubins paths q0 -> q1, shortest first; each verified to end at q1."""
    words = sorted(dubins_words(q0, q1, rho), key=lambda w: sum(w[1]))
    out = []
    for word, lengths in words:
        pts = dubins_sample(q0, word, lengths, rho, ds)
        if len(pts) and math.hypot(pts[-1, 0] - q1[0], pts[-1, 1] - q1[1]) < 1e-6 \
                and abs(float(wrap_angle(pts[-1, 2] - q1[2]))) < 1e-6:
            out.append(pts)
    return out


class HybridAStar:
    name = "hybrid_astar"
    description = "Hybrid A*: kinematic bicycle (3.0 m wheelbase) arcs over heading bins, Dubins shot."

    @dataclass
    class Params:
        step_m: float = field(1.5, lo=0.1, hi=20.0, doc="arc length of one expansion")
        steer_count: int = field(7, lo=3, hi=31, doc="steering angles per expansion (odd includes straight)")
        heading_bins: int = field(72, lo=8, hi=720, doc="heading bins of the closed set")
        xy_resolution_m: float = field(0.3, lo=0.02, hi=5.0, doc="position bin of the closed set")
        steer_cost: float = field(0.2, lo=0.0, hi=100.0, doc="extra cost per metre at full lock")
        steer_change_cost: float = field(0.5, lo=0.0, hi=100.0, doc="cost of a full-range steering change")
        heuristic_weight: float = field(1.0, lo=1.0, hi=10.0, doc="> 1: faster, less optimal")
        shot_distance_m: float = field(15.0, lo=0.0, hi=200.0, doc="try a Dubins shot to the goal within this")
        shot_radius_scale: float = field(1.5, lo=1.0, hi=20.0, doc="Dubins radius / minimum turning radius")
        shot_every: int = field(4, lo=1, hi=1000, doc="try the Dubins shot every n-th expansion in range")
        max_expansions: int = field(30_000, lo=10, hi=10_000_000, doc="search budget")

    def plan(self, grid: GridMap, start, goal, vehicle, collision, params, rng):
        checker = CollisionChecker(grid, vehicle, collision)
        start = np.asarray(start, dtype=np.float64)
        goal = np.asarray(goal, dtype=np.float64)
        smax = vehicle.max_steer_rad
        steers = np.linspace(-smax, smax, params.steer_count)
        kappas = np.tan(steers) / vehicle.wheelbase_m
        xyr = params.xy_resolution_m
        hbin = 2 * math.pi / params.heading_bins
        h_base = heuristic_field(grid, goal)
        w = params.heuristic_weight
        rho = vehicle.min_turn_radius_m * params.shot_radius_scale

        def key(pose):
            return (int(round(pose[0] / xyr)), int(round(pose[1] / xyr)),
                    int(round(pose[2] / hbin)) % params.heading_bins)

        def heuristic(pose):
            return w * h_base(pose)

        n_s = max(1, int(math.ceil(params.step_m / _SAMPLE_M)))
        s_along = np.linspace(params.step_m / n_s, params.step_m, n_s)
        straight = np.abs(kappas) < 1e-9
        safe_k = np.where(straight, 1.0, kappas)[:, None]

        def expand(node):
            x, y, th = node.pose
            t = th + kappas[:, None] * s_along[None]
            cx = np.where(straight[:, None], x + s_along * math.cos(th), x + (np.sin(t) - math.sin(th)) / safe_k)
            cy = np.where(straight[:, None], y + s_along * math.sin(th), y - (np.cos(t) - math.cos(th)) / safe_k)
            chains = np.empty((len(kappas), n_s + 1, 3))
            chains[:, 0] = node.pose
            chains[:, 1:, 0], chains[:, 1:, 1], chains[:, 1:, 2] = cx, cy, t
            ok = checker.chains_free(chains)
            prev = node.extra if node.extra is not None else 0.0
            out = []
            for c, st, good in zip(chains, steers, ok):
                if good:
                    cost = params.step_m * (1 + params.steer_cost * abs(st) / smax) \
                        + params.steer_change_cost * abs(st - prev) / (2 * smax)
                    out.append(Node(key(c[-1]), c[-1], node.g + cost, node, c, float(st)))
            return out

        tries = [0]

        def try_goal(node):
            if math.hypot(goal[0] - node.pose[0], goal[1] - node.pose[1]) > max(params.shot_distance_m, 1e-9):
                return None
            tries[0] += 1
            if (tries[0] - 1) % params.shot_every:
                return None
            for pts in dubins_path(node.pose, goal, rho)[:2]:
                chain = np.vstack([node.pose, pts])
                chain[-1] = goal
                if checker.chains_free([chain])[0]:
                    return chain
            return None

        path, expansions = astar(Node(key(start), start, 0.0), expand, heuristic, try_goal,
                                 params.max_expansions)
        return PlannerOutput(path, {"expansions": expansions})
