"""``roadtwin render``: synthetic perception data from a composed town (options only: what the
command does is ``roadtwin_core.apps.render``).

    roadtwin render out/town/town.usda --frames 100 --size 640x480 --stereo --events \\
        --formats kitti,mmseg,coco,depth,normal -o out/render
    roadtwin render out/highway/town.usda --rig survey --views defects:0.6 --randomize \\
        --classmap builtin:road_defects_br --frames 2000 --executor local -o out/survey

How cameras, appearance, randomization, class maps and executors are chosen: see
``roadtwin_core.apps.render.run``. The options become a :class:`~roadtwin_core.apps.render.RenderOptions`,
``--param KEY=VALUE`` a dict the app checks against the renderer's ``Params``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from .._console import console, err_console
from ..params import PARAM_HELP, parse_param_options
from ..render.rig_usd import add_rig_cameras, read_stage_cameras

__all__ = ["render", "rig_add", "rig_app"]


def render(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    frames: int = typer.Option(8, "--frames", help="number of frames (with --poses or stage cameras: at most theirs)"),
    rig: Optional[str] = typer.Option(None, "--rig", help="camera rig preset: survey | dashcam | stereo | inspection "
                                      "(size, field of view, height, pitch, baseline; explicit options override)"),
    views: Optional[str] = typer.Option(None, "--views", help="random (lane poses) | defects:SHARE[:clear][:NEAR-FAR] (that "
                                        "share of frames aimed at a pothole or crack NEAR-FAR m ahead, default 5-25; "
                                        ":clear = the rest without any). Default: the stage's camera prims, else random"),
    randomize: bool = typer.Option(False, "--randomize", help="per-frame domain randomization: sun, sky, weather, "
                                   "road tint and wear, verge and shoulder surfaces, exposure, white balance, "
                                   "noise, motion blur, vignetting, JPEG"),
    classmap: Optional[str] = typer.Option(None, "--classmap", help="class map TOML file or builtin:NAME (e.g. "
                                           "builtin:road_defects_br) for the labels; default: roadtwin's classes"),
    size: Optional[str] = typer.Option(None, "--size", help="image size WIDTHxHEIGHT (default: the rig's, else 640x480)"),
    stereo: bool = typer.Option(False, "--stereo", help="rectified stereo rig: right image, disparity, occlusion"),
    baseline: Optional[float] = typer.Option(None, "--baseline", help="stereo baseline in m (default: the rig's, "
                                             "else 0.54 as KITTI)"),
    events: bool = typer.Option(False, "--events", help="also simulate an event camera on a continuous drive"),
    formats: Optional[str] = typer.Option(None, "--formats", help="comma-separated: kitti,mmseg,coco,depth,normal "
                                          "or a plugin's dataset format "
                                          "(default: all that apply)"),
    seed: int = typer.Option(0, "--seed", help="random seed for poses and randomization"),
    hfov: Optional[float] = typer.Option(None, "--hfov", help="horizontal field of view in degrees (default: the "
                                         "rig's, else 90)"),
    height: Optional[float] = typer.Option(None, "--height", help="camera height above the road in m (default: the "
                                           "rig's, else 1.5)"),
    pitch: Optional[float] = typer.Option(None, "--pitch", help="camera pitch in degrees, negative looks down "
                                          "(default: the rig's)"),
    poses: Optional[Path] = typer.Option(None, "--poses", help="JSON poses file instead of lane sampling"),
    weather: str = typer.Option("clear", "--weather", help="clear | fog | wet | dusk (--randomize draws its own)"),
    material: Optional[str] = typer.Option(None, "--material", help="select the stage's roadMaterial variant "
                                           "(e.g. asphalt | cobblestone | cement; default: the stage's own)"),
    renderer: str = typer.Option("warp", "--renderer", help="renderer plugin name"),
    device: Optional[str] = typer.Option(None, "--device", help="cpu | cuda | cuda:N (default: the renderer's)"),
    backend: str = typer.Option("auto", "--backend", help="ray caster: auto | warp | open3d (CPU)"),
    executor: str = typer.Option("local", "--executor", help="local (process pool) | serial | ray (with --device cuda: one shard of frames a GPU)"),
    workers: Optional[int] = typer.Option(None, "--workers", help="local: worker processes (default: all cores; on a "
                                          "GPU device the frame-finishing processes, default cores - 1); serial: threads"),
    ray_address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster address (default: a local one)"),
    speed: float = typer.Option(8.0, "--speed", help="event drive speed in m/s"),
    event_rate: float = typer.Option(500.0, "--event-rate", help="event drive frame rate in Hz"),
    event_frames: int = typer.Option(50, "--event-frames", help="frames rendered for the event camera"),
    event_size: Optional[str] = typer.Option(None, "--event-size", help="event camera size (default: --size)"),
    event_threshold: float = typer.Option(0.2, "--event-threshold", help="mean log-intensity contrast threshold"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"renderer {PARAM_HELP}"),
) -> None:
    """Render RGB, labels, depth, normals, stereo and events from a composed town."""
    from ..apps.render import RenderOptions, run_render
    from ..apps.render.report import print_summary

    options = RenderOptions(frames=frames, rig=rig, views=views, randomize=randomize, classmap=classmap, size=size,
                            stereo=stereo, baseline=baseline, events=events, formats=formats, seed=seed, hfov=hfov,
                            height=height, pitch=pitch, poses=poses, weather=weather, material=material,
                            renderer=renderer, device=device, backend=backend, executor=executor, workers=workers,
                            ray_address=ray_address, speed=speed, event_rate=event_rate, event_frames=event_frames,
                            event_size=event_size, event_threshold=event_threshold,
                            renderer_params=parse_param_options(param))
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        tasks: dict[str, int] = {}

        def report(what: str, done: int, total: int) -> None:
            if what not in tasks:
                tasks[what] = bar.add_task(f"{what} frames", total=total)
            bar.update(tasks[what], completed=done)

        summary = run_render(stage, out, options, progress=report)
    print_summary(console, summary, out)


rig_app = typer.Typer(add_completion=False, no_args_is_help=True,
                      help="camera rigs as UsdGeom.Camera prims in a stage (used by roadtwin render)")


@rig_app.command("add")
def rig_add(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    rig: str = typer.Option("survey", "--rig", help="comma-separated presets: survey,dashcam,stereo,inspection"),
    at_s: float = typer.Option(20.0, "--at-s", help="default pose: metres along the stage's first driving lane"),
) -> None:
    """Write camera prims for rig presets into layers/cameras.usda (the stage's strongest sublayer)."""
    from ..apps.render.report import print_rig_cameras

    names = [r.strip() for r in rig.split(",") if r.strip()]
    layer = add_rig_cameras(stage, names, at_s=at_s)
    print_rig_cameras(console, layer, read_stage_cameras(stage))
