"""What ``roadtwin render`` and ``roadtwin rig add`` print."""
from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table

__all__ = ["print_rig_cameras", "print_summary"]


def print_summary(console: Console, summary: dict, out: Path) -> None:
    table = Table(title=f"rendered {Path(out).resolve()}")
    table.add_column("item")
    table.add_column("value", justify="right")
    for k in ("frames", "size", "rig", "stereo", "formats", "events", "poses", "randomize", "executor", "backend",
              "device"):
        v = summary[k]
        table.add_row(k, "x".join(map(str, v)) if k == "size" else ", ".join(v) if isinstance(v, list) else str(v))
    if summary["class_map"]:
        table.add_row("class map", summary["class_map"]["name"])
    for c, st in summary["defects"].items():
        table.add_row(f"frames with {c}", f"{st['frames_with']:.0%} (mean {st['mean_pixel_share']:.2%} of pixels)")
    table.add_row("time (s)", " / ".join(f"{k} {v:.2f}" for k, v in summary["timings_s"].items()))
    table.add_row("frames / s", f"{summary['frames_per_s']:.2f}")
    console.print(table)


def print_rig_cameras(console: Console, layer, cameras) -> None:
    table = Table(title=f"cameras in {layer}")
    for col in ("prim", "rig", "size", "fx (px)", "position (m)"):
        table.add_column(col)
    for c in cameras:
        k = c.intrinsics
        table.add_row(c.path, c.rig, f"{k.width}x{k.height}", f"{k.fx:.1f}",
                      ", ".join(f"{x:.2f}" for x in c.cam_to_world[:3, 3]))
    console.print(table)
