"""``roadtwin plan``: defect-aware path planning on a town stage (Zhang et al.'s comparison).

Registered in :mod:`roadtwin_core.cli` with ``app.command()(plan)``. Bad input raises
:class:`~roadtwin_core.RoadtwinError`, which ``roadtwin``'s ``main`` prints as one line (exit 2).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer

from ..errors import RoadtwinError
from ..params import PARAM_HELP, cli_params

MAX_RESOLUTION_M = 2.0
MAX_COORD_M = 1e7


def plan(
    stage: Path = typer.Argument(..., help="composed town (town.usda or its folder), or a layout: composed first into OUT/town"),
    planner: Optional[str] = typer.Option(None, "--planner", "-p",
                                          help="planner plugin: astar, rrtstar, lattice, hybrid_astar (default hybrid_astar)"),
    start: Optional[str] = typer.Option(None, "--start", help="X,Y,YAW in m, m, rad (default: the stage's planStart)"),
    goal: Optional[str] = typer.Option(None, "--goal", help="X,Y,YAW in m, m, rad (default: the stage's planGoal)"),
    collision: str = typer.Option("wheel", "--collision", help="wheel: per-tire footprints (may straddle); body: whole vehicle"),
    all_planners: bool = typer.Option(False, "--all", help="run every registered planner, write a comparison table"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    resolution: float = typer.Option(0.2, "--resolution", help="grid cell size in m"),
    seed: int = typer.Option(0, "--seed", help="random seed (sampling planners)"),
    sweep: Optional[Path] = typer.Option(None, "--sweep", help="roadtwin sweep output: decide bypass vs cross per defect on the route"),
    max_g: float = typer.Option(1.0, "--max-g", help="with --sweep: cross when g at the recommended speed is at most this"),
    vehicle: Optional[Path] = typer.Option(None, "--vehicle", help="vehicle file (.toml/.json); default: the paper's car "
                                           "(roadtwin_core/vehicle/paper_car.toml). With --sweep, the car the sweep drove"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"planner {PARAM_HELP} (one --planner)"),
) -> None:
    """Plan a path around road defects: grid maps of the stage, planner(s), metrics, plots, USD curve."""
    from ..apps.plan import plan_stage
    from ..apps.plan.report import print_run
    from ..planning import parse_pose
    from ..atomic import output_path
    from ..vehicle import load_full_vehicle, paper_car

    output_path(out, "dir")
    if all_planners and planner is not None:
        raise RoadtwinError("give --planner NAME or --all, not both")
    if seed < 0:
        raise RoadtwinError(f"--seed must be >= 0, got {seed}")
    # a cell wider than a lane cannot tell a wheel path from a defect: the grid is meaningless
    if math.isfinite(resolution) and resolution > MAX_RESOLUTION_M:   # the rest: plan_stage's checks
        raise RoadtwinError(f"--resolution must be at most {MAX_RESOLUTION_M:g} m, got {resolution}")
    if not math.isfinite(max_g) or max_g < 0:
        raise RoadtwinError(f"--max-g must be a finite number >= 0, got {max_g}")
    for what, text in (("--start", start), ("--goal", goal)):
        if text is not None and max(map(abs, parse_pose(text, what))) > MAX_COORD_M:
            raise RoadtwinError(f"{what} {text!r} is absurdly far (coordinates beyond {MAX_COORD_M:g} m)")
    car = load_full_vehicle(vehicle, paper_car())
    names = None if all_planners else [planner or "hybrid_astar"]
    planner_params = planner_param_values(param, names)
    run = plan_stage(stage, out, planners=names, start=start, goal=goal, collision=collision,
                     resolution=resolution, seed=seed, vehicle=car, sweep=sweep, max_g=max_g,
                     planner_params=planner_params)
    print_run(run, stage, collision, names is not None, sweep, max_g)


def planner_param_values(param: list[str] | None, names: list[str] | None) -> dict | None:
    """``--param`` for the one planner run (planners take different parameters), checked now."""
    import dataclasses

    from ..plugins import get_plugin_manager

    if not param:
        return None
    if names is None:
        raise RoadtwinError("--param needs one --planner NAME (planners take different parameters)")
    planner = get_plugin_manager().get("planners", names[0])
    return dataclasses.asdict(cli_params(param, planner.Params, f"planner {names[0]}"))
