"""``roadtwin render``: synthetic perception data from a composed town.

    roadtwin render out/town/town.usda --frames 100 --size 640x480 --stereo --events \\
        --formats kitti,mmseg,coco,depth,normal -o out/render

Appearance is the stage's: the UsdPreviewSurface materials and textures bound to its meshes
(``--material`` only picks a variant of the root's ``roadMaterial`` variant set, in memory).
Cameras: ``--frames`` random poses on the driving lanes' centerlines (``--height`` m above the
road, looking down the lane with random yaw / pitch / roll jitter, seeded), or the poses of a
``--poses`` JSON file. ``--events`` adds a continuous drive along one lane (``--speed`` m/s,
``--event-rate`` Hz, ``--event-frames`` frames) rendered and fed to the event camera simulator.
Everything is checked before the output directory is touched (size, formats, weather, renderer,
stage, poses, cameras inside geometry) and the directory is written whole or not at all.
The renderer is a plugin, found by name (``--renderer``, default ``warp``).
"""
from __future__ import annotations

import dataclasses
import re
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import typer
from ._console import console
from rich.table import Table

from .atomic import atomic_output_dir
from .errors import RoadtwinError
from .params import check_params

Progress = Callable[[str, int, int], None]


def parse_size(text: str, what: str = "--size") -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if not m:
        raise RoadtwinError(f"{what} must look like WIDTHxHEIGHT (e.g. 640x480), got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if w <= 0 or h <= 0:
        raise RoadtwinError(f"{what} must be at least 1x1 pixels, got {text!r}")
    if w > 16384 or h > 16384:
        raise RoadtwinError(f"{what} is too large (at most 16384 pixels a side), got {text!r}")
    return w, h


def run_render(stage: str | Path, out: str | Path, *, frames: int = 8, size: str = "640x480", stereo: bool = False,
               baseline: float = 0.54, events: bool = False, formats: str | None = None, seed: int = 0,
               hfov: float = 90.0, height: float = 1.5, poses: str | Path | None = None, weather: str = "clear",
               material: str | None = None, renderer: str = "warp", device: str | None = None, backend: str = "auto",
               speed: float = 8.0, event_rate: float = 500.0, event_frames: int = 50, event_size: str | None = None,
               event_threshold: float = 0.2, pm=None, progress: Progress | None = None) -> dict:
    """Render a dataset; returns the summary (also the basis of meta.json)."""
    from .plugins import get_plugin_manager
    from .render import (Camera, DatasetWriter, EventSimulator, GroundSampler, Intrinsics, RenderParams,
                         StereoCamera, WEATHERS, build_render_mesh, lane_trajectory, load_poses_file,
                         parse_formats, sample_lane_poses, stage_lanes)
    from .usd.town_reader import load_town

    t0 = time.perf_counter()
    report = progress or (lambda *_: None)
    stage = Path(stage)
    width, height_px = parse_size(size)
    fmt = parse_formats(formats, stereo)
    if frames < 1:
        raise RoadtwinError(f"--frames must be >= 1, got {frames}")
    if seed < 0:
        raise RoadtwinError(f"--seed must be >= 0, got {seed}")
    if not (height > 0 and np.isfinite(height)):
        raise RoadtwinError(f"--height must be > 0 m, got {height}")
    if weather not in WEATHERS:
        raise RoadtwinError(f"unknown weather {weather!r} (known: {', '.join(WEATHERS)})")
    intr = Intrinsics.from_fov(width, height_px, hfov)
    if stereo and not (baseline > 0 and np.isfinite(baseline)):
        raise RoadtwinError(f"--baseline must be > 0 m, got {baseline}")
    ev_w, ev_h = parse_size(event_size, "--event-size") if event_size else (width, height_px)
    if events:
        if event_frames < 2:
            raise RoadtwinError(f"--event-frames must be >= 2, got {event_frames}")
        if not event_threshold > 0:
            raise RoadtwinError(f"--event-threshold must be > 0, got {event_threshold}")
        try:
            import h5py  # noqa: F401
        except ImportError:
            raise RoadtwinError("--events writes HDF5 and needs h5py (pip install h5py)") from None
    params = check_params(RenderParams(weather=weather, seed=seed, device=device, backend=backend), "render")

    pm = pm or get_plugin_manager()
    rend = pm.get("renderers", renderer)
    if not stage.exists():
        raise RoadtwinError(f"{stage}: no such file")
    town = load_town(stage, looks=True, variants={"roadMaterial": material} if material else None)
    mesh = build_render_mesh(town, defect_types=pm.registry("defect_types").keys())
    lanes = stage_lanes(stage)
    rng = np.random.default_rng(seed)
    ground = None

    def ground_fn():
        nonlocal ground
        if ground is None:
            ground = GroundSampler(mesh)
        return ground

    if poses is not None:
        pose_list = load_poses_file(poses)[:frames]
        pose_source = str(poses)
        g = ground_fn()(np.array([p[:3, 3][:2] for p in pose_list]))
        for k, (p, z) in enumerate(zip(pose_list, g)):
            where = f"{poses}: camera {k} at ({p[0, 3]:.2f}, {p[1, 3]:.2f}, {p[2, 3]:.2f})"
            if np.isfinite(z) and p[2, 3] < z:
                raise RoadtwinError(f"{where} is below the road surface (z = {z:.2f} there)")
            if np.isfinite(z) and p[2, 3] < z + params.min_clearance_m:
                raise RoadtwinError(f"{where} is inside geometry: {p[2, 3] - z:.3f} m above the road "
                                    f"(minimum clearance {params.min_clearance_m} m)")
    elif lanes:
        pose_list = sample_lane_poses(lanes, frames, rng, ground_fn(), height=height)
        pose_source = "lanes"
    else:
        raise RoadtwinError(f"{stage}: no cameras or poses: the stage has no driving lane centerlines "
                            "(roadtwin:segment:centerline) and no --poses file was given")
    cams = [Camera(intr, p) for p in pose_list]
    if stereo:
        cams = [StereoCamera(c, baseline) for c in cams]

    prepared = rend.prepare(mesh, params) if hasattr(rend, "prepare") else mesh
    frame_iter = rend.render(prepared, cams, params)       # checks every camera first
    ev_iter = None
    if events:
        if not lanes:
            raise RoadtwinError(f"{stage}: --events drives along a lane, but the stage has no driving lane centerlines")
        ev_times, ev_poses = lane_trajectory(lanes, np.random.default_rng([seed, 1]), ground_fn(), speed=speed,
                                             rate_hz=event_rate, n_frames=event_frames, height=height)
        ev_intr = Intrinsics.from_fov(ev_w, ev_h, hfov)
        ev_iter = rend.render(prepared, [Camera(ev_intr, p) for p in ev_poses], dataclasses.replace(params, shade=True))
    t_setup = time.perf_counter()

    with atomic_output_dir(out) as tmp:
        writer = DatasetWriter(tmp, fmt, intr, mesh.classes, mesh.instances, baseline if stereo else None,
                               categories=mesh.defect_types)
        for k, frame in enumerate(frame_iter):
            writer.add(frame)
            report("render", k + 1, len(cams))
        t_frames = time.perf_counter()
        n_events = 0
        if ev_iter is not None:
            sim = EventSimulator(ev_w, ev_h, threshold=event_threshold, seed=seed)
            chunks = []
            for k, (frame, t) in enumerate(zip(ev_iter, ev_times)):
                chunks.append(sim.step(frame.rgb, float(t)))
                report("events", k + 1, len(ev_times))
            ev = {key: np.concatenate([c[key] for c in chunks]) for key in ("x", "y", "t", "p")}
            n_events = len(ev["t"])
            writer.write_events(ev, ev_times, ev_poses, (ev_w, ev_h),
                                {**sim.params(), "speed_mps": speed, "rate_hz": event_rate})
        t_events = time.perf_counter()
        summary = {
            "stage": str(stage), "renderer": renderer, "frames": len(cams), "size": [width, height_px],
            "stereo": bool(stereo), "formats": fmt, "events": n_events, "poses": pose_source,
            "render_params": dataclasses.asdict(params), "material": material, "seed": seed,
            "backend": getattr(prepared, "backend", None), "device": getattr(prepared, "device", None),
            "timings_s": {"setup": round(t_setup - t0, 3), "frames": round(t_frames - t_setup, 3),
                          "events": round(t_events - t_frames, 3)},
        }
        writer.finish({"render": summary})
    return summary


def render(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    frames: int = typer.Option(8, "--frames", help="number of frames (with --poses: at most the file's poses)"),
    size: str = typer.Option("640x480", "--size", help="image size WIDTHxHEIGHT"),
    stereo: bool = typer.Option(False, "--stereo", help="rectified stereo rig: right image, disparity, occlusion"),
    baseline: float = typer.Option(0.54, "--baseline", help="stereo baseline in m (KITTI: 0.54)"),
    events: bool = typer.Option(False, "--events", help="also simulate an event camera on a continuous drive"),
    formats: Optional[str] = typer.Option(None, "--formats", help="comma-separated: kitti,mmseg,coco,depth,normal "
                                          "(default: all that apply)"),
    seed: int = typer.Option(0, "--seed", help="random seed for poses"),
    hfov: float = typer.Option(90.0, "--hfov", help="horizontal field of view in degrees"),
    height: float = typer.Option(1.5, "--height", help="camera height above the road in m"),
    poses: Optional[Path] = typer.Option(None, "--poses", help="JSON poses file instead of lane sampling"),
    weather: str = typer.Option("clear", "--weather", help="clear | fog | wet | dusk"),
    material: Optional[str] = typer.Option(None, "--material", help="select the stage's roadMaterial variant "
                                           "(e.g. asphalt | cobblestone | cement; default: the stage's own)"),
    renderer: str = typer.Option("warp", "--renderer", help="renderer plugin name"),
    device: Optional[str] = typer.Option(None, "--device", help="cpu | cuda | cuda:N (default: the renderer's)"),
    backend: str = typer.Option("auto", "--backend", help="ray caster: auto | warp | open3d (CPU)"),
    speed: float = typer.Option(8.0, "--speed", help="event drive speed in m/s"),
    event_rate: float = typer.Option(500.0, "--event-rate", help="event drive frame rate in Hz"),
    event_frames: int = typer.Option(50, "--event-frames", help="frames rendered for the event camera"),
    event_size: Optional[str] = typer.Option(None, "--event-size", help="event camera size (default: --size)"),
    event_threshold: float = typer.Option(0.2, "--event-threshold", help="mean log-intensity contrast threshold"),
) -> None:
    """Render RGB, labels, depth, normals, stereo and events from a composed town."""
    summary = run_render(stage, out, frames=frames, size=size, stereo=stereo, baseline=baseline, events=events,
                         formats=formats, seed=seed, hfov=hfov, height=height, poses=poses, weather=weather,
                         material=material, renderer=renderer, device=device, backend=backend, speed=speed,
                         event_rate=event_rate, event_frames=event_frames, event_size=event_size,
                         event_threshold=event_threshold)
    table = Table(title=f"rendered {Path(out).resolve()}")
    table.add_column("item")
    table.add_column("value", justify="right")
    for k in ("frames", "size", "stereo", "formats", "events", "poses", "backend", "device"):
        v = summary[k]
        table.add_row(k, "x".join(map(str, v)) if k == "size" else ", ".join(v) if isinstance(v, list) else str(v))
    table.add_row("time (s)", " / ".join(f"{k} {v:.2f}" for k, v in summary["timings_s"].items()))
    console.print(table)
