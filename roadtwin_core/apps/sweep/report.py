"""What ``roadtwin sweep`` prints: the recommendation per defect and the run totals."""
from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table

__all__ = ["print_report"]


def print_report(console: Console, result: dict, out: Path, backend: str, n_speeds: int) -> None:
    s = result["summary"]
    table = Table(title=f"sweep: {s['defects']} defect(s) x {n_speeds} speed(s) on {backend}")
    for col in ("defect", "type", "recommended km/h", "g there", "g max (at km/h)", "comfortable up to", "note"):
        table.add_column(col)
    for r in result["recommendations"][:50]:
        fmt = (lambda v: "-" if v is None else f"{v:.3g}")
        table.add_row(str(r["defect"]), str(r.get("defect_type", "")), fmt(r["recommended_speed_kmh"]),
                      fmt(r["g_at_recommended"]), f"{fmt(r.get('g_max'))} ({fmt(r.get('speed_of_g_max_kmh'))})",
                      fmt(r["max_comfortable_speed_kmh"]), str(r["note"]))
    console.print(table)
    console.print(f"{s['runs']} runs + {s['runs']} twin runs, {s['simulated_vehicle_s']:.1f} vehicle-s simulated in "
                  f"{s['simulation_wall_s']:.2f} s on {s['device']} (real-time factor {s['realtime_factor']:.1f}x); "
                  f"wrote {out}", highlight=False)
    for note in s.get("notes", []):
        console.print(f"note: {note}", highlight=False)
    if s["off_road_runs"]:
        console.print(f"note: {s['off_road_runs']} run(s) left the road (see the off_road column)", highlight=False)
