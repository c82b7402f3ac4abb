"""``roadtwin plan``: defect-aware path planning on a town stage (Zhang et al.'s comparison).

Options only: what the command does, its checks included, is
:func:`roadtwin_core.apps.plan.plan_stage`. Bad input raises :class:`~roadtwin_core.RoadtwinError`,
which ``roadtwin``'s ``main`` prints as one line (exit 2).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import RoadtwinError
from ..params import PARAM_HELP, parse_param_options

__all__ = ["plan"]


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

    if all_planners and planner is not None:
        raise RoadtwinError("give --planner NAME or --all, not both")
    names = None if all_planners else [planner or "hybrid_astar"]
    run = plan_stage(stage, out, planners=names, start=start, goal=goal, collision=collision,
                     resolution=resolution, seed=seed, vehicle=vehicle, sweep=sweep, max_g=max_g,
                     planner_params=parse_param_options(param))
    print_run(run, stage, collision, names is not None, sweep, max_g)
