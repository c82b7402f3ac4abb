"""``roadtwin drive``: a vehicle drives a route through a composed town while the sensors of a rig
record it on one simulation clock (options only: what the command does is
``roadtwin_core.apps.drive``).

    roadtwin drive out/town/town.usda -o out/drive --length 100 --speed 30
    roadtwin drive out/town/town.usda -o out/drive --rig rig.toml --sensors imu,lidar \\
        --speed-profile out/sweep/recommendations.json
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .._console import console, err_console
from ..atomic import output_path
from ..params import PARAM_HELP, parse_param_options

__all__ = ["drive"]


def drive(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    route: str = typer.Option("auto", "--route", help="auto | lane:ID[,ID...] | a route file (x y rows, TUM, JSON)"),
    length: Optional[float] = typer.Option(100.0, "--length", help="route length (m)"),
    duration: Optional[float] = typer.Option(None, "--duration", help="stop after this many simulated seconds"),
    speed: float = typer.Option(30.0, "--speed", help="speed (km/h); the cruise speed with --speed-profile"),
    speed_profile: Optional[Path] = typer.Option(None, "--speed-profile",
                                                 help="a sweep's recommendations.json: cross each defect at its "
                                                      "recommended speed"),
    vehicle: Optional[Path] = typer.Option(None, "--vehicle", help="vehicle file (.toml/.json); default: the built-in car"),
    backend: str = typer.Option("warp", "--backend", help="physics backend plugin: warp | pybullet | ..."),
    device: str = typer.Option("cpu", "--device", help="physics device: cpu | cuda | cuda:N"),
    renderer: str = typer.Option("warp", "--renderer", help="renderer plugin for the cameras"),
    rig: Optional[Path] = typer.Option(None, "--rig", help="rig file (TOML); default: the paper's platform"),
    sensors: Optional[str] = typer.Option(None, "--sensors", help="sensor names of the rig to record (default: all)"),
    bag: bool = typer.Option(True, "--bag/--no-bag", help="write the ROS 2 bag (MCAP storage)"),
    rrd: bool = typer.Option(True, "--rerun/--no-rerun", help="write drive.rrd"),
    compressed: bool = typer.Option(False, "--compressed", help="images as sensor_msgs/CompressedImage (JPEG)"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"renderer {PARAM_HELP}"),
) -> None:
    """Drive a vehicle through a town and record its sensors (ROS 2 bag, rerun, contact events)."""
    from ..apps.drive import DriveOptions, run_drive

    output_path(out, "dir")
    opt = DriveOptions(route=route, length_m=length, duration_s=duration, speed_kmh=speed,
                       speed_profile=speed_profile, vehicle=vehicle, backend=backend, device=device,
                       renderer=renderer, rig=rig, sensors=sensors, bag=bag, rrd=rrd, compressed=compressed,
                       render_params=parse_param_options(param) if param else {})
    res = run_drive(stage, out, opt, progress=lambda m: err_console.print(f"[dim]{m}[/]", highlight=False))
    console.print(f"drove {res['driven_m']:.1f} m in {res['duration_s']:.2f} s ({res['route']}); "
                  f"{res['contacts']} wheel-defect contacts; "
                  + ", ".join(f"{k}: {v['samples']}" for k, v in res["sensors"].items()) + f" -> {out}",
                  highlight=False)
