"""``roadtwin plan``: grid maps of a town, planner(s), outputs, written atomically.

:func:`plan_stage` in four parts: its options checked (:func:`check_plan_options`, every bound
once, here where Python callers and the command both enter), the planners and the stage read,
the town to plan on (composed first from a layout) with its grid and reference route, then each
planner run and its outputs written (:func:`_plan_and_write`), and the comparison for several.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ...atomic import atomic_output_dir, output_path
from ...errors import RoadtwinError
from ...params import apply_params
from ...planning import (COLLISION_MODES, CollisionChecker, Footprint, GridMap, PlanFailure, PlanResult, check_endpoint,
                         parse_pose, plan_path, polyline_length, rasterize_scene, reference_path)
from ...plugins import get_plugin_manager
from ...usd.checks import MAX_COORD_M   # start / goal coordinates beyond it are a typo, not a road
from ...usd.town_reader import load_town
from ...usd.validate import validate_stage
from ...vehicle import VehicleParams, load_full_vehicle, paper_car
from ..compose.run import compose
from .decisions import decide, load_recommendations, sweep_vehicle_name, write_decisions
from .plots import write_plot
from .usd_layer import write_path_layer, write_paths_index
from .writers import write_comparison_csv, write_metrics_json, write_path_csv

__all__ = ["MAX_RESOLUTION_M", "PlanRun", "check_plan_options", "plan_stage"]

MAX_RESOLUTION_M = 2.0   # a cell wider than a lane cannot tell a wheel path from a defect

Pose = tuple[float, float, float]


@dataclass
class PlanRun:
    outdir: Path
    town: Path
    grid: GridMap
    results: list[PlanResult | PlanFailure] = field(default_factory=list)
    start: Pose = (0.0, 0.0, 0.0)
    goal: Pose = (0.0, 0.0, 0.0)
    composed: bool = False
    decisions: list = field(default_factory=list)   # bypass / cross per defect on the route (--sweep)


def plan_stage(stage: str | Path, outdir: str | Path, *, planners: Sequence[str] | None = None,
               start: str | Sequence[float] | None = None, goal: str | Sequence[float] | None = None,
               collision: str = "wheel", resolution: float = 0.2, seed: int = 0,
               vehicle: VehicleParams | str | Path | None = None, pm=None, validate: bool = True,
               sweep: str | Path | None = None, max_g: float = 1.0,
               planner_params: dict[str, Any] | None = None) -> PlanRun:
    """``roadtwin plan``: grid maps of a composed town (or a layout, composed first into
    ``OUTDIR/town``), one or more planners, and their outputs, written atomically to ``outdir``.

    ``planners=None`` runs every registered planner, each into its own subfolder, plus
    ``comparison.csv``, ``comparison.png`` and ``paths.usda``; one planner writes straight into
    ``outdir``: ``path.csv``, ``path.usda``, ``metrics.json``, ``plot.png``.

    ``vehicle`` (a :class:`~roadtwin_core.vehicle.VehicleParams` or a vehicle file; default: the
    paper's car, ``paper_car.toml``, so the paper's figures stay) is planned for through its
    footprint; with ``sweep`` the decisions use the same car's rows and a sweep that drove
    another car is refused. ``planner_params``: values for the one planner's ``Params``
    (``--param``), checked like a layout's.
    """
    output_path(outdir, "dir")
    start, goal = check_plan_options(start, goal, collision, resolution, seed, max_g)
    vehicle = vehicle if isinstance(vehicle, VehicleParams) else load_full_vehicle(vehicle, paper_car())
    footprint = vehicle.footprint()
    pm = pm or get_plugin_manager()
    impls = _planners(pm, planners, planner_params)
    params = _planner_params(impls, planner_params)
    single = planners is not None and len(impls) == 1

    stage, outdir = _stage_path(stage), Path(outdir).resolve()
    if stage.resolve().is_relative_to(outdir):
        raise RoadtwinError(f"{stage}: lies inside the output directory {outdir}, which plan replaces")
    scene = load_town(stage)
    composed = not scene.colliders
    if composed and not scene.roads:
        raise RoadtwinError(f"{stage}: neither a composed town (no collision meshes) nor a layout (no road segments)")
    if sweep is not None:
        load_recommendations(sweep)  # a bad sweep folder, or one of another car, fails before any work
        sweep_vehicle_name(sweep, vehicle)
    start = start or _stage_pose(scene.metadata, "planStart", "start", stage)
    goal = goal or _stage_pose(scene.metadata, "planGoal", "goal", stage)

    with atomic_output_dir(outdir) as tmp:
        town, scene, town_ref = _town_to_plan_on(stage, scene, composed, tmp, pm)
        grid = rasterize_scene(scene, resolution)
        ref = _reference_route(grid, footprint, collision, start, goal)
        run = PlanRun(outdir, outdir / "town" / "town.usda" if composed else town, grid, [], start, goal, composed)
        if sweep is not None:
            run.decisions = decide(grid, ref, vehicle, sweep, max_g)
            write_decisions(tmp, run.decisions)
        outputs = _Outputs(stage, run.town, scene.name, town_ref, validate)
        for name, impl in impls:
            result = _plan_and_write(impl, name, run, ref, footprint, collision, seed, params, pm,
                                     tmp if single else tmp / name, outputs, single)
            run.results.append(result)
        ok = [r for r in run.results if isinstance(r, PlanResult)]
        if not ok:
            raise RoadtwinError("no planner found a path: " + "; ".join(f"{r.planner}: {r.reason}" for r in run.results))
        if not single:
            _write_comparison(tmp, run, ok, footprint, collision, outputs)
    return run


def check_plan_options(start: str | Sequence[float] | None, goal: str | Sequence[float] | None, collision: str,
                       resolution: float, seed: int, max_g: float) -> tuple[Pose | None, Pose | None]:
    """Every numeric option in its bounds and the given start / goal poses parsed (None: the
    stage's default, read later); one RoadtwinError naming the option otherwise."""
    if seed < 0:
        raise RoadtwinError(f"--seed must be >= 0, got {seed}")
    if not (math.isfinite(resolution) and resolution > 0):
        raise RoadtwinError(f"--resolution must be a positive number of metres, got {resolution}")
    if resolution > MAX_RESOLUTION_M:
        raise RoadtwinError(f"--resolution must be at most {MAX_RESOLUTION_M:g} m, got {resolution}")
    # 0 is meaningful: cross only where the sweep measured no vibration at all (decisions.decide: g <= max_g)
    if not math.isfinite(max_g) or max_g < 0:
        raise RoadtwinError(f"--max-g must be a finite number >= 0, got {max_g}")
    poses = _given_pose(start, "start"), _given_pose(goal, "goal")
    if collision not in COLLISION_MODES:
        raise RoadtwinError(f"unknown collision level {collision!r} (known: {', '.join(COLLISION_MODES)})")
    return poses


def _given_pose(value: str | Sequence[float] | None, what: str) -> Pose | None:
    if value is None:
        return None
    if isinstance(value, str):
        pose = parse_pose(value, f"--{what}")
    else:
        v = [float(x) for x in value]
        if len(v) != 3 or not all(math.isfinite(x) for x in v):
            raise RoadtwinError(f"--{what} must be X,Y,YAW, got {value!r}")
        pose = (v[0], v[1], v[2])
    if max(map(abs, pose)) > MAX_COORD_M:
        raise RoadtwinError(f"--{what} {value!r} is absurdly far (coordinates beyond {MAX_COORD_M:g} m)")
    return pose


def _stage_pose(metadata: dict, key: str, what: str, stage: Path) -> Pose:
    """The stage's default start or goal (``roadtwin:layout:planStart`` / ``planGoal``)."""
    if key not in metadata:
        raise RoadtwinError(f"{stage}: no --{what} given and the stage has no roadtwin:layout:{key} default")
    return parse_pose(str(metadata[key]), f"{stage}: roadtwin:layout:{key}")


def _planners(pm, planners: Sequence[str] | None, planner_params: dict | None) -> list[tuple[str, Any]]:
    """The planners to run by name: the given ones, or every registered one (registration order,
    the built-ins': the paper's). An unknown name fails before any work."""
    if planner_params and (planners is None or len(planners) != 1):
        raise RoadtwinError("--param needs one --planner NAME (planners take different parameters)")
    if planners is None:
        names = list(pm.registry("planners"))
        if not names:
            raise RoadtwinError("no planners are registered (is the roadtwin planners plugin installed?)")
    else:
        names = list(planners)
    return [(n, pm.get("planners", n)) for n in names]


def _planner_params(impls: list[tuple[str, Any]], values: dict | None) -> dict | None:
    """``--param`` values for the one planner run, typed and bounds-checked against its ``Params``."""
    if not values:
        return None
    (name, impl), = impls
    return dataclasses.asdict(apply_params(impl.Params, values, f"planner {name}"))


def _stage_path(stage: str | Path) -> Path:
    stage = Path(stage)
    return stage / "town.usda" if stage.is_dir() else stage


def _town_to_plan_on(stage: Path, scene, composed: bool, tmp: Path, pm) -> tuple[Path, Any, Callable[[Path], str]]:
    """(the town's stage, its scene, how a layer in a folder refers to it). A layout is composed
    first into ``tmp/town`` (the output's town, referred to by a relative path)."""
    if not composed:
        town = stage.resolve()
        return town, scene, lambda d: str(town)
    town = compose(stage, tmp / "town", pm=pm).town
    return town, load_town(town), lambda d: os.path.relpath(tmp / "town" / "town.usda", d).replace(os.sep, "/")


def _reference_route(grid: GridMap, footprint: Footprint, collision: str, start: Pose, goal: Pose) -> np.ndarray:
    """The route along the lanes from start to goal; both poses must be free for the vehicle."""
    base = CollisionChecker(grid, footprint, collision)
    check_endpoint(base, start, "start")
    check_endpoint(base, goal, "goal")
    return reference_path(grid, start, goal)  # raises when the goal is not connected


@dataclass(frozen=True)
class _Outputs:
    """What every written output names: the stage planned, the town it refers to, and whether
    the USD layers are validated."""

    stage: Path
    town: Path
    scene_name: str
    town_ref: Callable[[Path], str]   # the town as a layer reference from a folder
    validate: bool


def _plan_and_write(impl, name: str, run: PlanRun, ref: np.ndarray, footprint: Footprint, collision: str, seed: int,
                    params: dict | None, pm, folder: Path, outputs: _Outputs, single: bool) -> PlanResult | PlanFailure:
    """One planner's path and its files in ``folder``; with several planners a planner that finds
    no path is a PlanFailure in the comparison, alone it is the error."""
    grid, t0 = run.grid, time.perf_counter()
    try:
        r = plan_path(grid, impl, run.start, run.goal, footprint=footprint, collision=collision, seed=seed,
                      reference_length=polyline_length(ref), pm=pm, params=params)
    except RoadtwinError as exc:
        if single:
            raise
        return PlanFailure(name, collision, str(exc).split(": ", 1)[-1], time.perf_counter() - t0)
    folder.mkdir(exist_ok=True)
    write_path_csv(folder / "path.csv", r)
    write_metrics_json(folder / "metrics.json", r, {"stage": str(outputs.stage), "town": str(outputs.town),
                                                    "grid": grid.summary(), "vehicle": footprint.as_dict(),
                                                    "reference_path": ref.tolist()})
    write_plot(folder / "plot.png", grid, [r], footprint, f"{outputs.stage.name}: {name}")
    write_path_layer(folder / "path.usda", outputs.town_ref(folder), outputs.scene_name, [r], grid, footprint)
    if outputs.validate:
        _validate(folder / "path.usda")
    return r


def _write_comparison(folder: Path, run: PlanRun, ok: list[PlanResult], footprint: Footprint, collision: str,
                      outputs: _Outputs) -> None:
    """Several planners: the comparison table and figure, and one USD layer with every path."""
    write_comparison_csv(folder / "comparison.csv", run.results)
    write_plot(folder / "comparison.png", run.grid, ok, footprint, f"{outputs.stage.name}: {collision}-level collision")
    write_paths_index(folder / "paths.usda", outputs.scene_name, [f"./{r.planner}/path.usda" for r in ok])
    if outputs.validate:
        _validate(folder / "paths.usda")


def _validate(path: Path) -> None:
    errors = [f for f in validate_stage(path) if f.severity == "Error"]
    if errors:
        raise RoadtwinError(f"{path.name} fails validation: {errors[0].validator}: {errors[0].message}")
