"""plan's console report: the paper's comparison table, warnings, the decisions, what was written."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from rich.table import Table

from ..._console import console, err_console
from ...planning import PlanFailure
from .stage import PlanRun


def comparison_table(results: Iterable, title: str = "path planning") -> Table:
    """The paper's table: one row per planner (and collision level)."""
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


def print_run(run: PlanRun, stage: Path, collision: str, single: bool, sweep: Path | None, max_g: float) -> None:
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
    if not single:
        console.print(f"wrote {run.outdir}/comparison.csv, comparison.png, paths.usda and one folder per planner",
                      highlight=False)
    else:
        console.print(f"wrote {run.outdir}/path.csv, path.usda, metrics.json, plot.png", highlight=False)
