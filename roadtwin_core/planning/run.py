"""Run one planner plugin from start to goal and measure its path."""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from ..errors import RoadtwinError
from ..params import make_params
from ..plugins import get_plugin_manager
from .grid import GridMap
from .collision import CollisionChecker, check_endpoint
from .footprint import Footprint, wrap_angle
from .metrics import PathMetrics, path_metrics
from .reference import polyline_length, reference_path


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
    stats: dict[str, Any] = field(default_factory=dict)   # the planner's own counts (expansions ...)

    def as_dict(self) -> dict[str, Any]:
        return {"planner": self.planner, "collision": self.collision, "seed": self.seed,
                "start": list(self.start), "goal": list(self.goal), "time_s": round(self.time_s, 4),
                "poses": len(self.poses), "params": self.params, "metrics": self.metrics.as_dict()}


@dataclass
class PlannerOutput:
    """What a planner's ``plan`` returns: the poses (None: no path) and its per-call statistics.

    The statistics travel with the result rather than on the planner object, which the plugin
    manager shares between calls (and which process or Ray executors copy), so concurrent plans
    never overwrite each other's counts."""

    poses: Any
    stats: dict[str, Any] = field(default_factory=dict)


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


def plan_path(grid: GridMap, planner: Any, start: Sequence[float], goal: Sequence[float], *,
              footprint: Footprint, collision: str = "wheel", params: dict[str, Any] | None = None,
              seed: int = 0, reference_length: float | None = None, pm=None) -> PlanResult:
    """Run one planner (a registered name or an object) and measure its path."""
    if isinstance(planner, str):
        planner = (pm or get_plugin_manager()).get("planners", planner)
    checker = CollisionChecker(grid, footprint, collision)
    start = tuple(float(v) for v in start)
    goal = tuple(float(v) for v in goal)
    check_endpoint(checker, start, "start")
    check_endpoint(checker, goal, "goal")
    if reference_length is None:
        reference_length = polyline_length(reference_path(grid, start, goal))
    p = make_params(planner.Params, dict(params or {}), f"planner {planner.name}")
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    out = planner.plan(grid, start, goal, footprint, collision, p, rng)
    poses, stats = (out.poses, dict(out.stats)) if isinstance(out, PlannerOutput) else (out, {})
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
    metrics = path_metrics(grid, poses, footprint, collision, reference_length)
    return PlanResult(planner.name, collision, poses, grid.road_height(poses[:, :2]), metrics, dt,
                      asdict(p), seed, start, goal, stats)

