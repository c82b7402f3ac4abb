"""RRT*: a sampling-based tree in (x, y) with rewiring (Karaman & Frazzoli), fixed budget.

Samples are uniform over the drivable cells within ``corridor_m`` of the reference midline (the
whole road on a straight street; on a town map the route's corridor), plus a goal bias; a new vertex is at most
``steer_m`` from its nearest tree vertex; among the ``neighbours`` nearest tree vertices within
``rewire_radius_m`` the one giving the cheapest collision-free connection becomes its parent, and
neighbours that get cheaper through it are rewired. Edges are straight; cost = path length. After
``iterations`` samples the cheapest collision-free connection to the exact goal pose wins.
Deterministic for a given rng seed. No smoothing: the paper compares the raw RRT* path.

Footprint models, as for the grid A* (``footprint``):

* ``lane`` (default): the vehicle keeps the lane heading (direction of the nearest segment of
  the reference midline) at every vertex and moves between vertices without turning on the
  spot; an edge's check depends only on its two ends.
* ``motion``: heading = edge direction, the vehicle turns on the spot at vertices (at most
  ``max_turn_deg``); an edge's check includes the turn at its parent, and rewiring re-checks the
  turns towards the rewired vertex's children.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import RoadtwinError, field
from roadtwin_core.planning import CollisionChecker, PlannerOutput, reference_frame, reference_path, wrap_angle

from ._search import dedupe


class RRTStar:
    name = "rrtstar"
    description = "RRT* in (x, y): uniform samples on the lanes, rewiring, fixed iteration budget."

    @dataclass
    class Params:
        footprint: str = "lane"  # "lane" or "motion" (see the module docstring)
        iterations: int = field(2000, lo=10, hi=1_000_000, doc="number of samples")
        steer_m: float = field(2.0, lo=0.05, hi=50.0, doc="longest new edge")
        rewire_radius_m: float = field(3.0, lo=0.05, hi=50.0, doc="neighbourhood for parent choice and rewiring")
        neighbours: int = field(12, lo=1, hi=1000, doc="at most this many nearest vertices are considered")
        goal_bias: float = field(0.1, lo=0.0, hi=1.0, doc="probability of sampling the goal")
        max_turn_deg: float = field(60.0, lo=1.0, hi=180.0, doc="largest turn on the spot (footprint motion)")
        corridor_m: float = field(15.0, lo=0.5, hi=1e6, doc="sample only drivable cells this close to the midline")

    def plan(self, grid, start, goal, vehicle, collision, params, rng):
        if params.footprint not in ("lane", "motion"):
            raise RoadtwinError(f"planner rrtstar: parameter footprint must be 'lane' or 'motion', got {params.footprint!r}")
        lane_mode = params.footprint == "lane"
        checker = CollisionChecker(grid, vehicle, collision)
        start = np.asarray(start, dtype=np.float64)
        goal = np.asarray(goal, dtype=np.float64)
        res = grid.resolution
        corridor, lane = reference_frame(grid, reference_path(grid, start, goal))
        lane = np.nan_to_num(lane)
        iy_c, ix_c = np.nonzero(grid.drivable & (np.nan_to_num(corridor, nan=np.inf) <= params.corridor_m))
        centres = grid.cell_to_world(ix_c, iy_c)
        cap = params.iterations + 1
        xy = np.zeros((cap, 2))
        yaw = np.zeros(cap)          # lane: the vertex's heading; motion: heading of its incoming edge
        cost = np.zeros(cap)
        parent = np.full(cap, -1, np.int64)
        children: list[list[int]] = [[]]
        xy[0], yaw[0] = start[:2], start[2]
        n = 1
        steer = params.steer_m
        radius = max(params.rewire_radius_m, steer * 1.0001)
        max_turn = math.radians(params.max_turn_deg) + 1e-9

        def lane_yaw(p):
            ix, iy = grid.world_to_cell(p)
            return float(lane[iy, ix])

        def edge(i: int, p: np.ndarray, p_yaw: float) -> np.ndarray | None:
            """Chain from vertex i to point p arriving with ``p_yaw``; None if the turn is too big."""
            x, y = xy[i]
            if lane_mode:
                if i == 0:  # the start pose: turn on the spot to the lane heading first
                    y0 = lane_yaw(xy[0])
                    return np.array([[x, y, yaw[0]], [x, y, yaw[0] + wrap_angle(y0 - yaw[0])],
                                     [p[0], p[1], yaw[0] + wrap_angle(y0 - yaw[0]) + wrap_angle(p_yaw - y0)]])
                return np.array([[x, y, yaw[i]], [p[0], p[1], yaw[i] + wrap_angle(p_yaw - yaw[i])]])
            turn = float(wrap_angle(p_yaw - yaw[i]))
            if abs(turn) > max_turn:
                return None
            return np.array([[x, y, yaw[i]], [x, y, yaw[i] + turn], [p[0], p[1], yaw[i] + turn]])

        def arrival_yaw(i: int, p: np.ndarray) -> float:
            if lane_mode:
                return lane_yaw(p)
            return math.atan2(p[1] - xy[i, 1], p[0] - xy[i, 0])

        def check(chains):
            """chains may hold None (refused turns): those are not free."""
            ok = np.zeros(len(chains), bool)
            idx = [k for k, c in enumerate(chains) if c is not None]
            if idx:
                ok[idx] = checker.chains_free([chains[k] for k in idx])
            return ok

        for _ in range(params.iterations):
            if rng.random() < params.goal_bias:
                q = goal[:2].copy()
            else:
                q = centres[rng.integers(len(centres))] + (rng.random(2) - 0.5) * res
            d2 = ((xy[:n] - q) ** 2).sum(axis=1)
            i_near = int(np.argmin(d2))
            dist = math.sqrt(d2[i_near])
            if dist < 1e-6:
                continue
            new = xy[i_near] + (q - xy[i_near]) * min(1.0, steer / dist)
            if not grid.sample(grid.drivable, new, False):
                continue
            dn = np.sqrt(((xy[:n] - new) ** 2).sum(axis=1))
            near = np.flatnonzero((dn <= radius) & (dn > 1e-9))
            if len(near) == 0:
                continue
            near = near[np.argsort(dn[near], kind="stable")][:params.neighbours]
            order = near[np.argsort(cost[near] + dn[near], kind="stable")]
            chains = [edge(int(i), new, arrival_yaw(int(i), new)) for i in order]
            ok = check(chains)
            if not ok.any():
                continue
            k = int(np.argmax(ok))
            p = int(order[k])
            j = n
            n += 1
            xy[j], yaw[j], cost[j], parent[j] = new, chains[k][-1, 2], cost[p] + dn[p], p
            children.append([])
            children[p].append(j)
            # Rewire neighbours that get cheaper through the new vertex (one batched check).
            cand = [int(i) for i in near if i != p and i != 0 and cost[j] + dn[i] < cost[i] - 1e-9]
            if not cand:
                continue
            chains, owner, edges = [], [], {}
            for c in cand:
                e = edges[c] = edge(j, xy[c], arrival_yaw(j, xy[c]))
                chains.append(e)
                owner.append(c)
                if not lane_mode and e is not None:
                    for ch in children[c]:  # the turn at c towards each child
                        chains.append(np.array([[xy[c, 0], xy[c, 1], e[-1, 2]],
                                                [xy[c, 0], xy[c, 1], e[-1, 2] + wrap_angle(yaw[ch] - e[-1, 2])]]))
                        owner.append(c)
            ok = check(chains)
            owner = np.array(owner)
            for c in cand:
                e = edges[c]
                if e is None or not ok[owner == c].all():
                    continue
                if not lane_mode:
                    # Keep turns within the limit at c (its children's headings are unchanged).
                    if any(abs(float(wrap_angle(yaw[ch] - e[-1, 2]))) > max_turn for ch in children[c]):
                        continue
                children[parent[c]].remove(c)
                parent[c] = j
                yaw[c] = e[-1, 2]
                children[j].append(c)
                delta = cost[j] + dn[c] - cost[c]
                stack = [c]
                while stack:
                    v = stack.pop()
                    cost[v] += delta
                    stack.extend(children[v])

        # Cheapest collision-free connection to the exact goal pose.
        dg = np.sqrt(((xy[:n] - goal[:2]) ** 2).sum(axis=1))
        cands = np.flatnonzero(dg <= steer)
        cands = cands[np.argsort(cost[cands] + dg[cands], kind="stable")]
        for batch in np.array_split(cands, max(1, math.ceil(len(cands) / 16))):
            chains = []
            for i in batch:
                e = edge(int(i), goal[:2], arrival_yaw(int(i), goal[:2]) if dg[i] > 1e-9 else yaw[i])
                chains.append(None if e is None else np.vstack([e, [goal[0], goal[1], e[-1, 2] + wrap_angle(goal[2] - e[-1, 2])]]))
            ok = check(chains)
            if ok.any():
                k = int(np.argmax(ok))
                final = chains[k].copy()
                final[-1] = goal
                path = self._path(int(batch[k]), final, xy, yaw, parent, start, edge)
                return PlannerOutput(path, {"tree_size": n})
        return PlannerOutput(None, {"tree_size": n})

    @staticmethod
    def _path(last: int, final: np.ndarray, xy, yaw, parent, start, edge) -> np.ndarray:
        verts = []
        v = last
        while v > 0:
            verts.append(v)
            v = int(parent[v])
        verts.reverse()
        poses = [start]
        for v in verts:
            p = int(parent[v])
            chain = edge(p, xy[v], yaw[v])  # the same chain the tree accepted
            poses.extend(chain[1:])
        poses.extend(final[1:])
        return dedupe(np.array(poses, dtype=np.float64))
