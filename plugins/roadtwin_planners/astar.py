"""A*: grid search on the rear-axle cell (the paper's baseline), jagged by design.

The rear-axle point moves from cell centre to cell centre along ``connectivity`` directions
(8: the king's moves; 16 adds (2, 1)-type moves; 32 adds (3, 1) and (3, 2)). Two footprint
models (``footprint``):

* ``lane`` (default): the grid planner's view of the vehicle. The footprint keeps the lane's
  heading (the direction of the nearest segment of the reference midline, binned to
  ``heading_bin_deg``) while the point moves, so a lateral step is a sideways shift, not a 45
  degree turn of a 4.6 m car. State = cell. This is what makes grid A* usable on a 7 m road and
  what makes its path the jagged staircase the paper compares against.
* ``motion``: the vehicle points where it moves and turns on the spot at cells (state = cell +
  last direction; at most ``max_turn_deg`` per cell). Kinematically stricter; a 3.0 m wheelbase
  car driving at 45 (or even 18) degrees puts a front wheel 1.9-2.8 m to the side of its rear
  axle, so on a two-lane road it often cannot get back to the lane centre.

Every move inside the grid starts at a cell centre with a heading fixed by the move (and the
heading bins), so its swept footprint (wheel or body level, sampled by the core's collision
checker) is the same set of cell offsets from every cell: a "move is free" map per move type is
made by dilating the blocked cells with those offsets (lazily, when first needed), and the
search then costs one lookup per successor. The first move (from the exact start pose) and the
last one (to the exact goal pose, ending with a turn on the spot to the goal heading) are checked
directly. Cost = distance (+ optional cost per radian turned); heuristic = Euclidean distance,
so with ``heuristic_weight = 1`` the path is a shortest one in its state space. No smoothing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import RoadtwinError, field
from roadtwin_core.planning import (CollisionChecker, GridMap, PlannerOutput, lane_headings, reference_path,
                                    wrap_angle)

from ._search import Node, astar


def directions(connectivity: int) -> list[tuple[int, int]]:
    """Primitive grid steps sorted by angle: 8, 16 or 32 of them."""
    base = {8: [(1, 0), (1, 1)], 16: [(1, 0), (2, 1), (1, 1)], 32: [(1, 0), (3, 1), (2, 1), (3, 2), (1, 1)]}
    if connectivity not in base:
        raise RoadtwinError(f"planner astar: parameter connectivity must be 8, 16 or 32, got {connectivity}")
    octant = base[connectivity]
    steps = set()
    for x, y in octant:
        for a, b in ((x, y), (y, x)):
            for sx in (1, -1):
                for sy in (1, -1):
                    steps.add((sx * a, sy * b))
    return sorted(steps, key=lambda s: math.atan2(s[1], s[0]) % (2 * math.pi))


class AStar:
    name = "astar"
    description = "Grid A* over rear-axle cells (8/16/32-connected), turning on the spot: jagged by design."

    @dataclass
    class Params:
        footprint: str = "lane"  # "lane" or "motion" (see the module docstring)
        connectivity: int = field(8, lo=8, hi=32, doc="move directions: 8, 16 or 32")
        heading_bin_deg: float = field(2.5, lo=0.1, hi=45.0, doc="lane-heading bins (footprint lane)")
        max_turn_deg: float = field(45.0, lo=1.0, hi=135.0, doc="largest heading change at one cell")
        turn_cost_m_per_rad: float = field(0.0, lo=0.0, hi=100.0, doc="extra cost per radian turned")
        heuristic_weight: float = field(1.0, lo=1.0, hi=10.0, doc="> 1: faster, no longer shortest")
        max_expansions: int = field(2_000_000, lo=10, hi=50_000_000, doc="search budget")

    def plan(self, grid: GridMap, start, goal, vehicle, collision, params, rng):
        if params.footprint == "lane":
            search = _LaneSearch(grid, CollisionChecker(grid, vehicle, collision), start, goal, params)
        elif params.footprint == "motion":
            search = _MotionSearch(grid, CollisionChecker(grid, vehicle, collision), start, goal, params)
        else:
            raise RoadtwinError(f"planner astar: parameter footprint must be 'lane' or 'motion', got {params.footprint!r}")
        path, expansions = astar(search.start_node(), search.expand, search.heuristic, search.try_goal,
                                 params.max_expansions)
        return PlannerOutput(path, {"expansions": expansions, "maps_built": len(search.maps)})


class _GridSearch:
    """What both footprint models share: the grid, the start and goal poses and cells, the move
    directions, and the "move is free" maps made so far (keyed by move type)."""

    def __init__(self, grid: GridMap, checker: CollisionChecker, start, goal, params):
        self.checker = checker
        self.res = grid.resolution
        (self.x0, self.y0), (self.ny, self.nx) = grid.origin, grid.shape
        self.start = np.asarray(start, dtype=np.float64)
        self.goal = np.asarray(goal, dtype=np.float64)
        self.gx, self.gy = (int(v) for v in grid.world_to_cell(self.goal[:2]))
        self.sx, self.sy = (int(v) for v in grid.world_to_cell(self.start[:2]))
        self.dirs = directions(int(params.connectivity))
        self.drivable = grid.drivable
        self.w = params.heuristic_weight
        self.tc = params.turn_cost_m_per_rad
        self.maps: dict[tuple[int, ...], np.ndarray] = {}

    def heuristic(self, pose) -> float:
        return self.w * math.hypot(pose[0] - self.goal[0], pose[1] - self.goal[1])

    def centre(self, ix, iy) -> tuple[float, float]:
        return self.x0 + (ix + 0.5) * self.res, self.y0 + (iy + 0.5) * self.res

    def on_road(self, cx, cy) -> bool:
        return 0 <= cx < self.nx and 0 <= cy < self.ny and bool(self.drivable[cy, cx])


class _MotionSearch(_GridSearch):
    """Footprint ``motion``: state = cell + last direction; the vehicle turns on the spot at cells."""

    def __init__(self, grid: GridMap, checker: CollisionChecker, start, goal, params):
        super().__init__(grid, checker, start, goal, params)
        self.ang = ang = [math.atan2(dy, dx) for dx, dy in self.dirs]
        self.max_turn = max_turn = math.radians(params.max_turn_deg) + 1e-9
        self.turns = {d: [(d2, float(wrap_angle(ang[d2] - ang[d]))) for d2 in range(len(self.dirs))
                          if abs(float(wrap_angle(ang[d2] - ang[d]))) <= max_turn] for d in range(len(self.dirs))}

    def start_node(self) -> Node:
        return Node((self.sx, self.sy, -1), self.start, 0.0)

    def move_map(self, d, d2, turn) -> np.ndarray:
        m = self.maps.get((d, d2))
        if m is None:
            res = self.res
            y1 = self.ang[d] + turn
            dx, dy = self.dirs[d2]
            chain = np.array([[0.0, 0.0, self.ang[d]], [0.0, 0.0, y1], [dx * res, dy * res, y1]])
            m = self.maps[(d, d2)] = self.checker.motion_free_map(self.checker.densify(chain)[1:])
        return m

    def expand_start(self, node: Node) -> list[Node]:
        """From the exact start pose: turn on the spot to a move's direction, then move (checked directly)."""
        x, y, yaw = node.pose
        chains, meta = [], []
        for d, (dx, dy) in enumerate(self.dirs):
            cx, cy = self.sx + dx, self.sy + dy
            if not self.on_road(cx, cy):
                continue
            tx, ty = self.centre(cx, cy)
            turn = float(wrap_angle(self.ang[d] - yaw))
            if abs(turn) > self.max_turn:
                continue
            chains.append(np.array([[x, y, yaw], [x, y, yaw + turn], [tx, ty, yaw + turn]]))
            meta.append((cx, cy, d, math.hypot(tx - x, ty - y), abs(turn)))
        ok = self.checker.chains_free(chains) if chains else []
        return [Node((cx, cy, d), c[-1], node.g + dist + self.tc * turn, node, c)
                for c, (cx, cy, d, dist, turn), good in zip(chains, meta, ok) if good]

    def expand(self, node: Node) -> list[Node]:
        ix, iy, d = node.key
        if d < 0:
            return self.expand_start(node)
        out = []
        x, y, yaw = node.pose
        for d2, turn in self.turns[d]:
            dx, dy = self.dirs[d2]
            cx, cy = ix + dx, iy + dy
            if not self.on_road(cx, cy):
                continue
            if not self.move_map(d, d2, turn)[iy, ix]:
                continue
            tx, ty = self.centre(cx, cy)
            pose = np.array([tx, ty, yaw + turn])
            chain = np.array([node.pose, [x, y, yaw + turn], pose])
            out.append(Node((cx, cy, d2), pose, node.g + self.res * math.hypot(dx, dy) + self.tc * abs(turn), node,
                            chain))
        return out

    def try_goal(self, node: Node) -> np.ndarray | None:
        ix, iy, _ = node.key
        if max(abs(ix - self.gx), abs(iy - self.gy)) > 3:
            return None
        goal = self.goal
        x, y, yaw = node.pose
        psi = math.atan2(goal[1] - y, goal[0] - x) if math.hypot(goal[0] - x, goal[1] - y) > 1e-9 else yaw
        psi = yaw + float(wrap_angle(psi - yaw))
        if abs(psi - yaw) > self.max_turn:
            return None
        chain = np.array([[x, y, yaw], [x, y, psi], [goal[0], goal[1], psi], goal])
        return chain if self.checker.chains_free([chain])[0] else None


class _LaneSearch(_GridSearch):
    """Footprint ``lane``: state = cell; the footprint keeps the binned lane heading of its cell."""

    def __init__(self, grid: GridMap, checker: CollisionChecker, start, goal, params):
        super().__init__(grid, checker, start, goal, params)
        self.hbin = math.radians(params.heading_bin_deg)
        lane = np.nan_to_num(lane_headings(grid, reference_path(grid, self.start, self.goal)))
        self.lane_bin = np.round(lane / self.hbin).astype(np.int64)

    def start_node(self) -> Node:
        return Node((self.sx, self.sy), self.start, 0.0)

    def move_map(self, b, d, b2) -> np.ndarray:
        m = self.maps.get((b, d, b2))
        if m is None:
            res, hbin = self.res, self.hbin
            dx, dy = self.dirs[d]
            chain = np.array([[0.0, 0.0, b * hbin], [dx * res, dy * res, b * hbin + (b2 - b) * hbin]])
            m = self.maps[(b, d, b2)] = self.checker.motion_free_map(self.checker.densify(chain)[1:])
        return m

    def expand(self, node: Node) -> list[Node]:
        ix, iy = node.key
        x, y, yaw = node.pose
        hbin = self.hbin
        start_node = node.parent is None
        b = int(self.lane_bin[iy, ix])
        out, chains, meta = [], [], []
        for d, (dx, dy) in enumerate(self.dirs):
            cx, cy = ix + dx, iy + dy
            if not self.on_road(cx, cy):
                continue
            b2 = int(self.lane_bin[cy, cx])
            tx, ty = self.centre(cx, cy)
            pose = np.array([tx, ty, b2 * hbin])  # inside the grid, node yaw == its bin's heading
            turn = abs(pose[2] - yaw)
            cost = node.g + math.hypot(tx - x, ty - y) + self.tc * turn
            if start_node:
                # From the exact start pose: turn on the spot to the lane heading, then move.
                chains.append(np.array([node.pose, [x, y, b2 * hbin], pose]))
                meta.append(((cx, cy), pose, cost))
            elif self.move_map(b, d, b2)[iy, ix]:
                out.append(Node((cx, cy), pose, cost, node, np.array([node.pose, pose])))
        if chains:
            ok = self.checker.chains_free(chains)
            out += [Node(k, p, c, node, ch) for ch, (k, p, c), good in zip(chains, meta, ok) if good]
        return out

    def try_goal(self, node: Node) -> np.ndarray | None:
        ix, iy = node.key
        if max(abs(ix - self.gx), abs(iy - self.gy)) > 1:
            return None
        x, y, yaw = node.pose
        end = [self.goal[0], self.goal[1], yaw]
        chain = np.array([[x, y, yaw], end, self.goal])
        return chain if self.checker.chains_free([chain])[0] else None
