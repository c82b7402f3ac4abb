"""State lattice: A* over (x, y, heading) with a pre-sampled set of smooth curves.

Primitives are computed once per run in the vehicle frame: cubic curves
``y(x) = a x^2 + b x^3`` of fixed forward reach ``length_m`` that start straight (y'(0) = 0) and
end at a lateral offset ``d`` with a heading change ``k * heading_step_deg`` (k in -1, 0, 1), for
``d`` every ``lateral_step_m`` up to ``lateral_max_m``; a curve whose curvature exceeds the
vehicle's full lock (wheelbase / tan(max steer)) is dropped. The heading stays G1-continuous
across primitive joints, so the path is smooth by construction. Headings live on the lattice
``start_yaw + k * heading_step``; positions are continuous and binned by ``xy_resolution_m`` for
the closed set. Cost = arc length + ``turn_cost_m_per_rad`` x |heading change along the curve|.
Near the goal a cubic connection to the exact goal pose is tried (the "analytic expansion").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import field
from roadtwin_core.planning import CollisionChecker, GridMap, PlannerOutput, transform, wrap_angle

from ._search import Node, astar, heuristic_field

_SAMPLE_M = 0.1


def cubic_curve(L: float, d: float, phi: float, ds: float = _SAMPLE_M) -> tuple[np.ndarray, float, float]:
    """Local poses (M, 3) of y = a x^2 + b x^3 from (0, 0, 0) to (L, d, phi), sampled about every
    ``ds`` of arc, its max |curvature| and total |heading change|."""
    t = math.tan(phi)
    a = (3 * d - L * t) / L ** 2
    b = (L * t - 2 * d) / L ** 3
    xs = np.linspace(0.0, L, max(8, int(math.ceil(L / ds * 4))))
    y = a * xs ** 2 + b * xs ** 3
    dy = 2 * a * xs + 3 * b * xs ** 2
    ddy = 2 * a + 6 * b * xs
    kappa = np.abs(ddy) / (1 + dy ** 2) ** 1.5
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(y)))])
    q = np.linspace(0.0, s[-1], max(2, int(math.ceil(s[-1] / ds)) + 1))
    x_q = np.interp(q, s, xs)
    out = np.column_stack([x_q, np.interp(q, s, y), np.arctan(np.interp(q, s, dy))])
    out[-1] = (L, d, phi)
    turn = float(np.abs(np.diff(np.arctan(dy))).sum())
    return out, float(kappa.max()), turn


class StateLattice:
    name = "lattice"
    description = "State lattice: A* over (x, y, heading) with pre-sampled cubic curves (smooth)."

    @dataclass
    class Params:
        length_m: float = field(4.0, lo=0.5, hi=30.0, doc="forward reach of each primitive")
        lateral_max_m: float = field(1.6, lo=0.0, hi=10.0, doc="largest lateral offset of a primitive")
        lateral_step_m: float = field(0.2, lo=0.02, hi=5.0, doc="lateral offset spacing")
        heading_step_deg: float = field(10.0, lo=1.0, hi=90.0, doc="heading lattice spacing")
        xy_resolution_m: float = field(0.3, lo=0.02, hi=5.0, doc="closed-set bin size")
        turn_cost_m_per_rad: float = field(1.0, lo=0.0, hi=100.0, doc="extra cost per radian turned")
        heuristic_weight: float = field(1.0, lo=1.0, hi=10.0, doc="> 1: faster, less optimal")
        shot_distance_m: float = field(12.0, lo=0.0, hi=200.0, doc="try a direct curve to the goal within this")
        max_expansions: int = field(20_000, lo=10, hi=10_000_000, doc="search budget")

    def primitives(self, vehicle, params) -> list[tuple[np.ndarray, float, int]]:
        kmax = 1.0 / vehicle.min_turn_radius_m
        step = math.radians(params.heading_step_deg)
        n = int(math.floor(params.lateral_max_m / params.lateral_step_m + 1e-9))
        prims = []
        for k in (-1, 0, 1):
            for i in range(-n, n + 1):
                curve, kappa, turn = cubic_curve(params.length_m, i * params.lateral_step_m, k * step)
                if kappa <= kmax + 1e-9:
                    prims.append((curve, _arc(curve) + params.turn_cost_m_per_rad * turn, k))
        return prims

    def plan(self, grid: GridMap, start, goal, vehicle, collision, params, rng):
        checker = CollisionChecker(grid, vehicle, collision)
        start = np.asarray(start, dtype=np.float64)
        goal = np.asarray(goal, dtype=np.float64)
        prims = self.primitives(vehicle, params)
        local = np.concatenate([p[0] for p in prims])                    # (sum M, 3)
        split = np.cumsum([len(p[0]) for p in prims])[:-1]
        step = math.radians(params.heading_step_deg)
        nbins = max(1, int(round(2 * math.pi / step)))
        xyr = params.xy_resolution_m
        h_base = heuristic_field(grid, goal)
        w = params.heuristic_weight
        kmax = 1.0 / vehicle.min_turn_radius_m

        def heuristic(pose):
            return w * h_base(pose)

        def key(pose, hk):
            return (int(round(pose[0] / xyr)), int(round(pose[1] / xyr)), hk % nbins)

        def expand(node):
            x, y, yaw = node.pose
            xy = transform(node.pose[None], local[:, :2])[0]
            world = np.column_stack([xy, yaw + local[:, 2]])
            chains = [np.vstack([node.pose, c]) for c in np.split(world, split)]
            ok = checker.chains_free(chains)
            out = []
            for c, (_, cost, dk), good in zip(chains, prims, ok):
                if good:
                    hk = node.extra + dk
                    out.append(Node(key(c[-1], hk), c[-1], node.g + cost, node, c, hk))
            return out

        def try_goal(node):
            dx, dy = goal[0] - node.pose[0], goal[1] - node.pose[1]
            if math.hypot(dx, dy) > max(params.shot_distance_m, 1e-9):
                return None
            c, s = math.cos(node.pose[2]), math.sin(node.pose[2])
            lx, ly = c * dx + s * dy, -s * dx + c * dy
            phi = float(wrap_angle(goal[2] - node.pose[2]))
            if lx < 0.3 or abs(phi) > math.radians(60) or abs(math.atan2(ly, lx)) > math.radians(60):
                return None
            curve, kappa, _ = cubic_curve(lx, ly, phi)
            if kappa > kmax + 1e-9:
                return None
            xy = transform(node.pose[None], curve[:, :2])[0]
            chain = np.vstack([node.pose, np.column_stack([xy, node.pose[2] + curve[:, 2]])])
            chain[-1] = goal
            return chain if checker.chains_free([chain])[0] else None

        start_node = Node(key(start, 0), start, 0.0, extra=0)
        path, expansions = astar(start_node, expand, heuristic, try_goal, params.max_expansions)
        return PlannerOutput(path, {"expansions": expansions})


def _arc(curve: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(curve[:, :2], axis=0), axis=1).sum())
