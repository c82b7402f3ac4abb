"""``roadtwin plan``: grid maps of a town, planner(s), outputs, written atomically."""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from ...errors import RoadtwinError
from ...planning.grid import GridMap
from ...planning import (COLLISION_MODES, CollisionChecker, PlanFailure, PlanResult, check_endpoint, parse_pose,
                         plan_path, polyline_length, reference_path)
from ...vehicle import VehicleParams, paper_car
from .decisions import decide, load_recommendations, sweep_vehicle_name, write_decisions
from .plots import write_plot
from .usd_layer import write_path_layer, write_paths_index
from .writers import write_comparison_csv, write_metrics_json, write_path_csv


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
               vehicle: VehicleParams | None = None, pm=None, validate: bool = True,
               sweep: str | Path | None = None, max_g: float = 1.0,
               planner_params: dict[str, Any] | None = None) -> PlanRun:
    """``roadtwin plan``: grid maps of a composed town (or a layout, composed first into
    ``OUTDIR/town``), one or more planners, and their outputs, written atomically to ``outdir``.

    ``planners=None`` runs every registered planner, each into its own subfolder, plus
    ``comparison.csv``, ``comparison.png`` and ``paths.usda``; one planner writes straight into
    ``outdir``: ``path.csv``, ``path.usda``, ``metrics.json``, ``plot.png``.

    ``vehicle`` (default: the paper's car, ``paper_car.toml``, so the paper's figures stay) is
    planned for through its footprint; with ``sweep`` the decisions use the same car's rows and
    a sweep that drove another car is refused.
    """
    from ...atomic import atomic_output_dir
    from ...planning.grid import rasterize_scene
    from ...plugins import get_plugin_manager
    from ...usd.town_reader import load_town

    pm = pm or get_plugin_manager()
    vehicle = vehicle or paper_car()
    footprint = vehicle.footprint()
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
        load_recommendations(sweep)  # a bad sweep folder, or one of another car, fails before any work
        sweep_vehicle_name(sweep, vehicle)
        if not (math.isfinite(max_g) and max_g > 0):
            raise RoadtwinError(f"--max-g must be a positive number, got {max_g}")
    start = _pose_arg(start, scene.metadata, "planStart", "start", stage)
    goal = _pose_arg(goal, scene.metadata, "planGoal", "goal", stage)

    with atomic_output_dir(outdir) as tmp:
        if composed:
            from ..compose.run import compose

            town = compose(stage, tmp / "town", pm=pm).town
            scene = load_town(town)
            town_ref = lambda d: os.path.relpath(tmp / "town" / "town.usda", d).replace(os.sep, "/")  # noqa: E731
        else:
            town = stage.resolve()
            town_ref = lambda d: str(town)  # noqa: E731
        grid = rasterize_scene(scene, resolution)
        base = CollisionChecker(grid, footprint, collision)
        check_endpoint(base, start, "start")
        check_endpoint(base, goal, "goal")
        ref = reference_path(grid, start, goal)  # raises when the goal is not connected
        ref_len = polyline_length(ref)
        run = PlanRun(outdir, outdir / "town" / "town.usda" if composed else town, grid, [], start, goal, composed)
        if sweep is not None:
            run.decisions = decide(grid, ref, vehicle, sweep, max_g)
            write_decisions(tmp, run.decisions)
        for name in names:
            t0 = time.perf_counter()
            try:
                r = plan_path(grid, impls[name], start, goal, footprint=footprint, collision=collision, seed=seed,
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
                                                       "grid": grid.summary(), "vehicle": footprint.as_dict(),
                                                       "reference_path": ref.tolist()})
            write_plot(d / "plot.png", grid, [r], footprint, f"{stage.name}: {name}")
            write_path_layer(d / "path.usda", town_ref(d), scene.name, [r], grid, footprint)
            if validate:
                _validate(d / "path.usda")
        ok = [r for r in run.results if isinstance(r, PlanResult)]
        if not ok:
            raise RoadtwinError("no planner found a path: " + "; ".join(f"{r.planner}: {r.reason}" for r in run.results))
        if not single:
            write_comparison_csv(tmp / "comparison.csv", run.results)
            write_plot(tmp / "comparison.png", grid, ok, footprint, f"{stage.name}: {collision}-level collision")
            write_paths_index(tmp / "paths.usda", scene.name, [f"./{r.planner}/path.usda" for r in ok])
            if validate:
                _validate(tmp / "paths.usda")
    return run

def _validate(path: Path) -> None:
    from ...usd.validate import validate_stage

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
