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
from roadtwin_core.planning import (CollisionChecker, GridMap, PlannerOutput, reference_frame, reference_path,
                                    wrap_angle)

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

    def plan(self, grid: GridMap, start, goal, vehicle, collision, params, rng):
        if params.footprint not in ("lane", "motion"):
            raise RoadtwinError(f"planner rrtstar: parameter footprint must be 'lane' or 'motion', got {params.footprint!r}")
        lane_mode = params.footprint == "lane"
        checker = CollisionChecker(grid, vehicle, collision)
        start = np.asarray(start, dtype=np.float64)
        goal = np.asarray(goal, dtype=np.float64)
        corridor, lane = reference_frame(grid, reference_path(grid, start, goal))
        iy_c, ix_c = np.nonzero(grid.drivable & (np.nan_to_num(corridor, nan=np.inf) <= params.corridor_m))
        centres = grid.cell_to_world(ix_c, iy_c)
        tree = _Tree(grid, checker, np.nan_to_num(lane), start, params.iterations + 1, lane_mode,
                     math.radians(params.max_turn_deg) + 1e-9)
        steer = params.steer_m
        radius = max(params.rewire_radius_m, steer * 1.0001)
        for _ in range(params.iterations):
            new = tree.steer(_sample(rng, goal, centres, grid.resolution, params.goal_bias), steer)
            if new is None or not grid.sample(grid.drivable, new, False):
                continue
            near, dn = tree.near(new, radius, params.neighbours)
            if len(near) == 0:
                continue
            j = tree.connect(new, near, dn)
            if j is not None:
                tree.rewire(j, near, dn)
        return tree.connect_goal(start, goal, steer)


def _sample(rng, goal: np.ndarray, centres: np.ndarray, res: float, goal_bias: float) -> np.ndarray:
    """The goal with probability ``goal_bias``, else a uniform point in a corridor cell."""
    if rng.random() < goal_bias:
        return goal[:2].copy()
    return centres[rng.integers(len(centres))] + (rng.random(2) - 0.5) * res


class _Tree:
    """The RRT* tree, grown in place: vertex positions, headings (lane: the vertex's heading;
    motion: heading of its incoming edge), costs from the start and parent / children links."""

    def __init__(self, grid: GridMap, checker: CollisionChecker, lane: np.ndarray, start: np.ndarray,
                 capacity: int, lane_mode: bool, max_turn: float):
        self.grid, self.checker, self.lane = grid, checker, lane
        self.lane_mode, self.max_turn = lane_mode, max_turn
        self.xy = np.zeros((capacity, 2))
        self.yaw = np.zeros(capacity)
        self.cost = np.zeros(capacity)
        self.parent = np.full(capacity, -1, np.int64)
        self.children: list[list[int]] = [[]]
        self.xy[0], self.yaw[0] = start[:2], start[2]
        self.n = 1

    # ------------------------------------------------------------------ edges
    def lane_yaw(self, p) -> float:
        ix, iy = self.grid.world_to_cell(p)
        return float(self.lane[iy, ix])

    def edge(self, i: int, p: np.ndarray, p_yaw: float) -> np.ndarray | None:
        """Chain from vertex i to point p arriving with ``p_yaw``; None if the turn is too big."""
        xy, yaw = self.xy, self.yaw
        x, y = xy[i]
        if self.lane_mode:
            if i == 0:  # the start pose: turn on the spot to the lane heading first
                y0 = self.lane_yaw(xy[0])
                return np.array([[x, y, yaw[0]], [x, y, yaw[0] + wrap_angle(y0 - yaw[0])],
                                 [p[0], p[1], yaw[0] + wrap_angle(y0 - yaw[0]) + wrap_angle(p_yaw - y0)]])
            return np.array([[x, y, yaw[i]], [p[0], p[1], yaw[i] + wrap_angle(p_yaw - yaw[i])]])
        turn = float(wrap_angle(p_yaw - yaw[i]))
        if abs(turn) > self.max_turn:
            return None
        return np.array([[x, y, yaw[i]], [x, y, yaw[i] + turn], [p[0], p[1], yaw[i] + turn]])

    def arrival_yaw(self, i: int, p: np.ndarray) -> float:
        if self.lane_mode:
            return self.lane_yaw(p)
        return math.atan2(p[1] - self.xy[i, 1], p[0] - self.xy[i, 0])

    def check(self, chains) -> np.ndarray:
        """chains may hold None (refused turns): those are not free."""
        ok = np.zeros(len(chains), bool)
        idx = [k for k, c in enumerate(chains) if c is not None]
        if idx:
            ok[idx] = self.checker.chains_free([chains[k] for k in idx])
        return ok

    # ------------------------------------------------------------------ growing
    def steer(self, q: np.ndarray, steer: float) -> np.ndarray | None:
        """The point at most ``steer`` from the nearest vertex towards ``q`` (None on a vertex)."""
        d2 = ((self.xy[:self.n] - q) ** 2).sum(axis=1)
        i_near = int(np.argmin(d2))
        dist = math.sqrt(d2[i_near])
        if dist < 1e-6:
            return None
        return self.xy[i_near] + (q - self.xy[i_near]) * min(1.0, steer / dist)

    def near(self, new: np.ndarray, radius: float, neighbours: int) -> tuple[np.ndarray, np.ndarray]:
        """The (at most ``neighbours``) nearest vertices within ``radius`` of ``new``, nearest
        first, and every vertex's distance to it."""
        dn = np.sqrt(((self.xy[:self.n] - new) ** 2).sum(axis=1))
        near = np.flatnonzero((dn <= radius) & (dn > 1e-9))
        if len(near) == 0:
            return near, dn
        return near[np.argsort(dn[near], kind="stable")][:neighbours], dn

    def connect(self, new: np.ndarray, near: np.ndarray, dn: np.ndarray) -> int | None:
        """Add ``new`` under the neighbour giving the cheapest collision-free edge; its index."""
        order = near[np.argsort(self.cost[near] + dn[near], kind="stable")]
        chains = [self.edge(int(i), new, self.arrival_yaw(int(i), new)) for i in order]
        ok = self.check(chains)
        if not ok.any():
            return None
        k = int(np.argmax(ok))
        p = int(order[k])
        j = self.n
        self.n += 1
        self.xy[j], self.yaw[j], self.cost[j], self.parent[j] = new, chains[k][-1, 2], self.cost[p] + dn[p], p
        self.children.append([])
        self.children[p].append(j)
        return j

    def rewire(self, j: int, near: np.ndarray, dn: np.ndarray) -> None:
        """Rewire neighbours that get cheaper through vertex j (one batched check)."""
        xy, yaw, cost, children = self.xy, self.yaw, self.cost, self.children
        cand = [int(i) for i in near if i != self.parent[j] and i != 0 and cost[j] + dn[i] < cost[i] - 1e-9]
        if not cand:
            return
        chains, owner, edges = [], [], {}
        for c in cand:
            e = edges[c] = self.edge(j, xy[c], self.arrival_yaw(j, xy[c]))
            chains.append(e)
            owner.append(c)
            if not self.lane_mode and e is not None:
                for ch in children[c]:  # the turn at c towards each child
                    chains.append(np.array([[xy[c, 0], xy[c, 1], e[-1, 2]],
                                            [xy[c, 0], xy[c, 1], e[-1, 2] + wrap_angle(yaw[ch] - e[-1, 2])]]))
                    owner.append(c)
        ok = self.check(chains)
        owner = np.array(owner)
        for c in cand:
            e = edges[c]
            if e is None or not ok[owner == c].all():
                continue
            if not self.lane_mode:
                # Keep turns within the limit at c (its children's headings are unchanged).
                if any(abs(float(wrap_angle(yaw[ch] - e[-1, 2]))) > self.max_turn for ch in children[c]):
                    continue
            self._reparent(c, j, e[-1, 2], cost[j] + dn[c] - cost[c])

    def _reparent(self, c: int, j: int, c_yaw: float, delta: float) -> None:
        """Make j the parent of c and pass c's cost change on to its subtree."""
        self.children[self.parent[c]].remove(c)
        self.parent[c] = j
        self.yaw[c] = c_yaw
        self.children[j].append(c)
        stack = [c]
        while stack:
            v = stack.pop()
            self.cost[v] += delta
            stack.extend(self.children[v])

    # ------------------------------------------------------------------ the path
    def connect_goal(self, start: np.ndarray, goal: np.ndarray, steer: float) -> PlannerOutput:
        """Cheapest collision-free connection to the exact goal pose, and the path through it."""
        n, xy, yaw = self.n, self.xy, self.yaw
        dg = np.sqrt(((xy[:n] - goal[:2]) ** 2).sum(axis=1))
        cands = np.flatnonzero(dg <= steer)
        cands = cands[np.argsort(self.cost[cands] + dg[cands], kind="stable")]
        for batch in np.array_split(cands, max(1, math.ceil(len(cands) / 16))):
            chains = []
            for i in batch:
                e = self.edge(int(i), goal[:2], self.arrival_yaw(int(i), goal[:2]) if dg[i] > 1e-9 else yaw[i])
                chains.append(None if e is None else np.vstack([e, [goal[0], goal[1], e[-1, 2] + wrap_angle(goal[2] - e[-1, 2])]]))
            ok = self.check(chains)
            if ok.any():
                k = int(np.argmax(ok))
                final = chains[k].copy()
                final[-1] = goal
                return PlannerOutput(self.path(int(batch[k]), final, start), {"tree_size": n})
        return PlannerOutput(None, {"tree_size": n})

    def path(self, last: int, final: np.ndarray, start: np.ndarray) -> np.ndarray:
        verts = []
        v = last
        while v > 0:
            verts.append(v)
            v = int(self.parent[v])
        verts.reverse()
        poses = [start]
        for v in verts:
            p = int(self.parent[v])
            chain = self.edge(p, self.xy[v], self.yaw[v])  # the same chain the tree accepted
            poses.extend(chain[1:])
        poses.extend(final[1:])
        return dedupe(np.array(poses, dtype=np.float64))
