"""Path-planning benchmark: the paper's planner comparison on the defect-avoidance scenario.

Composes ``stages/defect_avoidance.usda`` (or the stage given) into a temporary folder,
rasterizes it at 0.2 m, then runs every registered planner with wheel-level and with body-level
collision from the stage's default start to its default goal, and prints the planning time
(median of ``--repeat`` runs) and the metrics table: length, deviation from the midline (%),
smoothness (mean heading change, rad/m), mean/min wheel clearance (m), whether a wheel entered
a defect.

Run: ``.venv/bin/python bench/plan.py [--stage PATH] [--repeat N] [--resolution 0.2]``
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from rich.console import Console

from roadtwin_core.apps.plan.report import comparison_table
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.planning.grid import rasterize_scene
from roadtwin_core.planning import parse_pose, plan_path, polyline_length, reference_path
from roadtwin_core.plugins import get_plugin_manager
from roadtwin_core.usd.town_reader import load_town
from roadtwin_core.vehicle import load_full_vehicle, paper_car

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stage", type=Path, default=ROOT / "stages" / "defect_avoidance.usda")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--resolution", type=float, default=0.2)
    ap.add_argument("--vehicle", type=Path, default=None, help="vehicle file (default: the paper's car)")
    args = ap.parse_args()
    console = Console()
    pm = get_plugin_manager()
    footprint = load_full_vehicle(args.vehicle, paper_car()).footprint()
    with tempfile.TemporaryDirectory() as tmp:
        scene = load_town(args.stage)
        if not scene.colliders:
            t0 = time.perf_counter()
            town = compose(args.stage, Path(tmp) / "town", pm=pm, preview=False).town
            console.print(f"composed {args.stage.name} in {time.perf_counter() - t0:.2f} s")
            scene = load_town(town)
        t0 = time.perf_counter()
        grid = rasterize_scene(scene, args.resolution)
        t_grid = time.perf_counter() - t0
        s = grid.summary()
        console.print(f"grid {s['shape'][1]} x {s['shape'][0]} cells at {grid.resolution} m in {t_grid * 1000:.0f} ms: "
                      f"drivable {s['drivable_area_m2']:.1f} m², {s['defects']} defects, {s['defect_area_m2']:.2f} m²")
        start = parse_pose(scene.metadata["planStart"], "planStart")
        goal = parse_pose(scene.metadata["planGoal"], "planGoal")
        ref = polyline_length(reference_path(grid, start, goal))
        console.print(f"start {start}, goal {goal}, midline reference {ref:.2f} m")
        names = list(pm.registry("planners"))
        for collision in ("wheel", "body"):
            results = []
            for name in names:
                times, r = [], None
                for _ in range(max(1, args.repeat)):
                    r = plan_path(grid, name, start, goal, footprint=footprint, collision=collision, reference_length=ref, pm=pm)
                    times.append(r.time_s)
                r.time_s = statistics.median(times)
                results.append(r)
                console.print(f"{name} ({collision}): {r.stats}", highlight=False)
            console.print(comparison_table(results, f"{args.stage.name}: {collision}-level collision, "
                                                    f"median of {max(1, args.repeat)} run(s)"))


if __name__ == "__main__":
    main()
