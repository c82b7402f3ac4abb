"""``roadtwin drive``: a vehicle drives a route through a composed town while the sensors of a rig
record it on one simulation clock (options only: what the command does is
``roadtwin_core.apps.drive``).

    roadtwin drive out/town/town.usda -o out/drive --length 100 --speed 30
    roadtwin drive out/town/town.usda -o out/drive --sensors stereo,imu --sensor-param stereo.width=1280 \\
        --sensor-param stereo.height=720
    roadtwin drive out/town/town.usda -o out/drive --rig rig.toml --sensors imu,lidar \\
        --speed-profile out/sweep/recommendations.json
    roadtwin drive out/town/town.usda -o out/drives --routes routes.txt --executor ray   # one drive a route
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from .._console import console, err_console
from ..atomic import output_path
from ..params import PARAM_HELP, parse_param_options

__all__ = ["drive"]


def drive(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    route: Optional[list[str]] = typer.Option(None, "--route", help="auto | lane:ID[,ID...] | a route file (x y rows, "
                                              "TUM, JSON); repeat it for several drives (default: auto)"),
    routes: Optional[Path] = typer.Option(None, "--routes", help="a text file, one route a line: one drive each, "
                                          "in OUT/route_NNN/"),
    executor: str = typer.Option("local", "--executor", help="several routes: local (process pool) | serial | ray"),
    workers: Optional[int] = typer.Option(None, "--workers", help="worker processes (default: all cores)"),
    ray_address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster address (default: a local "
                                              "one); its workers must share OUT's filesystem"),
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
    sensor_param: Optional[list[str]] = typer.Option(None, "--sensor-param", help="SENSOR.KEY=VALUE over the rig "
                                                     "file's (e.g. stereo.width=1280); repeatable"),
    bag: bool = typer.Option(True, "--bag/--no-bag", help="write the ROS 2 bag (MCAP storage)"),
    rrd: bool = typer.Option(True, "--rerun/--no-rerun", help="write drive.rrd"),
    compressed: bool = typer.Option(False, "--compressed", help="images as sensor_msgs/CompressedImage (JPEG)"),
    traffic: int = typer.Option(0, "--traffic", help="other vehicles on the lanes (kinematic: the cameras and LiDAR "
                                "see them, the physics does not; those whose path would meet the ego's are left out)"),
    traffic_speed: float = typer.Option(30.0, "--traffic-speed", help="their speed (km/h)"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"renderer {PARAM_HELP}"),
) -> None:
    """Drive a vehicle through a town and record its sensors (ROS 2 bag, rerun, contact events)."""
    from ..apps.drive import DriveOptions, read_routes_file, run_drive
    from ..apps.drive.rig import parse_sensor_params

    output_path(out, "dir")
    specs = list(route or []) + (read_routes_file(routes) if routes is not None else [])
    opt = DriveOptions(route=specs[0] if specs else "auto", length_m=length, duration_s=duration, speed_kmh=speed,
                       speed_profile=speed_profile, vehicle=vehicle, backend=backend, device=device,
                       renderer=renderer, rig=rig, sensors=sensors,
                       sensor_params=parse_sensor_params(sensor_param), bag=bag, rrd=rrd, compressed=compressed,
                       render_params=parse_param_options(param) if param else {}, traffic=traffic,
                       traffic_speed_kmh=traffic_speed)
    if len(specs) > 1 or routes is not None:
        _many(stage, out, opt, specs, executor, workers, ray_address)
        return
    res = run_drive(stage, out, opt, progress=lambda m: err_console.print(f"[dim]{m}[/]", highlight=False))
    console.print(f"drove {res['driven_m']:.1f} m in {res['duration_s']:.2f} s ({res['route']}); "
                  f"{res['contacts']} wheel-defect contacts; "
                  + ", ".join(f"{k}: {v['samples']}" for k, v in res["sensors"].items()) + f" -> {out}",
                  highlight=False)


def _many(stage, out, opt, specs, executor, workers, ray_address) -> None:
    from ..apps.drive import run_drives

    with Progress(TextColumn("drives"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        task = bar.add_task("drives", total=len(specs))
        res = run_drives(stage, out, opt, specs, executor, workers, ray_address,
                         progress=lambda done, total: bar.update(task, completed=done))
    for d in res["drives"]:
        console.print(f"{d['folder']}: drove {d['driven_m']:.1f} m in {d['duration_s']:.2f} s ({d['source']}); "
                      f"{d['contacts']} wheel-defect contacts", highlight=False)
    console.print(f"{len(res['drives'])} drives on executor {res['executor']} -> {out}", highlight=False)
