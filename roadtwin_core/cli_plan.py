"""``roadtwin plan``: defect-aware path planning on a town stage (Zhang et al.'s comparison).

Registered in :mod:`roadtwin_core.cli` with ``app.command()(plan)``. Bad input raises
:class:`~roadtwin_core.RoadtwinError`, which ``roadtwin``'s ``main`` prints as one line (exit 2).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Iterable, Optional

import typer
from ._console import console, err_console
from rich.table import Table

from .errors import RoadtwinError
from .params import PARAM_HELP, cli_params

MAX_RESOLUTION_M = 2.0
MAX_COORD_M = 1e7


def comparison_table(results: Iterable, title: str = "path planning") -> Table:
    """The paper's table: one row per planner (and collision level)."""
    from .planning import PlanFailure

    table = Table(title=title)
    for col, just in (("planner", "left"), ("collision", "left"), ("length m", "right"), ("deviation %", "right"),
                      ("smoothness rad/m", "right"), ("clearance m", "right"), ("min clear. m", "right"),
                      ("wheel in defect", "center"), ("time s", "right")):
        table.add_column(col, justify=just, no_wrap=col == "planner")
    for r in results:
        if isinstance(r, PlanFailure):
            table.add_row(r.planner, r.collision, "[red]no path[/]", "", "", "", "", "", f"{r.time_s:.2f}")
            continue
        m = r.metrics
        table.add_row(r.planner, r.collision, f"{m.length_m:.2f}", f"{m.deviation_pct:.2f}",
                      f"{m.smoothness_rad_per_m:.4f}", f"{m.mean_clearance_m:.2f}", f"{m.min_clearance_m:.2f}",
                      "[red]yes[/]" if m.wheel_in_defect else "no", f"{r.time_s:.2f}")
    return table


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
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"planner {PARAM_HELP} (one --planner)"),
) -> None:
    """Plan a path around road defects: grid maps of the stage, planner(s), metrics, plots, USD curve."""
    from .planning import PlanFailure, plan_stage

    from .usd.checks import output_path

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
    from .planning import parse_pose

    for what, text in (("--start", start), ("--goal", goal)):
        if text is not None and max(map(abs, parse_pose(text, what))) > MAX_COORD_M:
            raise RoadtwinError(f"{what} {text!r} is absurdly far (coordinates beyond {MAX_COORD_M:g} m)")
    names = None if all_planners else [planner or "hybrid_astar"]
    from .plugins import get_plugin_manager

    if param and names is None:
        raise RoadtwinError("--param needs one --planner NAME (planners take different parameters)")
    planner_params = dataclasses.asdict(cli_params(param, get_plugin_manager().get("planners", names[0]).Params,
                                                   f"planner {names[0]}")) if param else None
    run = plan_stage(stage, out, planners=names, start=start, goal=goal, collision=collision,
                     resolution=resolution, seed=seed, sweep=sweep, max_g=max_g, planner_params=planner_params)
    if not console.is_terminal:  # a log or a pipe: do not squeeze the table into 80 columns
        console.width = max(console.width, 130)
    s, g = run.start, run.goal
    title = (f"{Path(stage).name}: ({s[0]:g}, {s[1]:g}, {s[2]:g}) -> ({g[0]:g}, {g[1]:g}, {g[2]:g}), "
             f"{collision}-level, grid {run.grid.resolution:g} m")
    console.print(comparison_table(run.results, title))
    for r in run.results:
        if isinstance(r, PlanFailure):
            err_console.print(f"warning: {r.planner}: {r.reason}", highlight=False, soft_wrap=True)
    if sweep is not None:
        table = Table(title=f"defects on the route: bypass or cross (sweep {sweep}, max g {max_g:g})")
        for col in ("defect", "type", "decision", "speed km/h", "g", "why"):
            table.add_column(col)
        for d in run.decisions:
            table.add_row(d.defect, d.defect_type, d.decision, "-" if d.speed_kmh is None else f"{d.speed_kmh:g}",
                          "-" if d.g_at_speed is None else f"{d.g_at_speed:.2f}", d.reason)
        console.print(table)
        console.print(f"wrote {run.outdir}/decisions.csv, decisions.json", highlight=False)
    if run.composed:
        console.print(f"composed {run.town}", highlight=False)
    if names is None:
        console.print(f"wrote {run.outdir}/comparison.csv, comparison.png, paths.usda and one folder per planner",
                      highlight=False)
    else:
        console.print(f"wrote {run.outdir}/path.csv, path.usda, metrics.json, plot.png", highlight=False)
