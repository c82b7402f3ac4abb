"""``roadtwin render``: synthetic perception data from a composed town.

    roadtwin render out/town/town.usda --frames 100 --size 640x480 --stereo --events \\
        --formats kitti,mmseg,coco,depth,normal -o out/render
    roadtwin render out/highway/town.usda --rig survey --views defects:0.6 --randomize \\
        --classmap builtin:road_defects_br --frames 2000 --executor local -o out/survey

Appearance is the stage's: the UsdPreviewSurface materials and textures bound to its meshes
(``--material`` only picks a variant of the root's ``roadMaterial`` variant set, in memory).
Cameras, first that applies: a ``--poses`` JSON file; ``--views defects:SHARE[:clear]`` (the
view sampler: that share of frames aimed at a pothole or crack 5-25 m ahead, the rest along the
lanes) or ``--views random`` (random lane poses, ``--height`` m above the road, yaw / pitch / roll
jitter); the stage's ``UsdGeom.Camera`` prims (``roadtwin rig add``); random lane poses.
``--rig`` sets size, field of view, height, pitch and stereo baseline from a preset
(``cameras.RIG_PRESETS``); explicit ``--size/--hfov/--height/--pitch/--baseline`` override it.
``--randomize`` draws per frame (``randomize.draw(seed, i)``) the sun, sky, weather, road tint and
wear, verge and shoulder surfaces (applied by the renderer, ``scene_look``) and a camera model
(``apply_sensor``: blur, vignetting, exposure, noise, white balance, JPEG; images are the JPEG
bytes); labels are untouched. ``--classmap`` maps the labels to a dataset's classes with the
frame's ego lane (``ego_lane``) and grows thin classes (``[dilate_px]``). Frames are rendered in
chunks on ``--executor`` (local pool, serial, Ray); frame i depends only on (seed, i), so every
executor writes the same bytes. ``--events`` adds a continuous drive along one lane (``--speed``
m/s, ``--event-rate`` Hz, ``--event-frames`` frames) fed to the event camera simulator.
Everything is checked before the output directory is touched (size, formats, weather, renderer,
stage, poses, rig, views, class map) and the directory is written whole or not at all.
The renderer is a plugin, found by name (``--renderer``, default ``warp``).
"""
from __future__ import annotations

import dataclasses
import math
import os
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
from .params import PARAM_HELP, check_params, cli_params

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


MAX_FRAMES = 1_000_000


def check_range(option: str, value, lo: float, hi: float, unit: str = "") -> None:
    """A numeric option must be finite and within [lo, hi] (NaN fails every comparison)."""
    try:
        ok = value is not None and math.isfinite(float(value)) and lo <= value <= hi
    except (TypeError, ValueError, OverflowError):   # e.g. an int beyond float range
        ok = False
    if not ok:
        unit = f" {unit}" if unit else ""
        raise RoadtwinError(f"{option} must be within {lo:g}..{hi:g}{unit}, got {value}")


def parse_views(text: str | None) -> tuple[str, float | None, str]:
    """``random`` | ``defects:SHARE`` | ``defects:SHARE:clear`` -> (kind, share, background)."""
    if text is None:
        return "none", None, "uniform"
    t = str(text).strip().lower()
    if t == "random":
        return "random", None, "uniform"
    m = re.fullmatch(r"defects:([0-9]*\.?[0-9]+)(?::(clear|uniform))?", t)
    if m:
        share = float(m.group(1))
        if 0.0 <= share <= 1.0:
            return "defects", share, m.group(2) or "uniform"
    raise RoadtwinError(f"--views must be random or defects:SHARE[:clear] with SHARE in 0..1 "
                        f"(e.g. defects:0.6), got {text!r}")


def _pick(explicit, preset_value, default):
    return explicit if explicit is not None else preset_value if preset_value is not None else default


def nearest_lane(lanes, cam_to_world: np.ndarray, max_offset_m: float):
    """(lane, s) of the chained lane a camera drives in: the nearest centreline within
    ``max_offset_m`` whose travel direction agrees with the camera's heading; None if none."""
    from .render.view_sampler import project_to_lane

    f = cam_to_world[:3, 2]
    h = np.array([f[0], f[1]])
    if np.linalg.norm(h) < 1e-9:
        return None
    xy = cam_to_world[:2, 3]
    best = None
    for lane in lanes:
        s, lat = project_to_lane(lane, xy[None])
        d = abs(float(lat[0]))
        heading = float(lane.heading(np.array([s[0]]), window=2.0)[0])
        if d <= max_offset_m and np.dot(h, [np.cos(heading), np.sin(heading)]) > 0 and (best is None or d < best[2]):
            best = (lane, float(s[0]), d)
    return None if best is None else best[:2]


def run_render(stage: str | Path, out: str | Path, *, frames: int = 8, size: str | None = None, stereo: bool = False,
               baseline: float | None = None, events: bool = False, formats: str | None = None, seed: int = 0,
               hfov: float | None = None, height: float | None = None, pitch: float | None = None,
               poses: str | Path | None = None, weather: str = "clear",
               material: str | None = None, renderer: str = "warp", device: str | None = None, backend: str = "auto",
               speed: float = 8.0, event_rate: float = 500.0, event_frames: int = 50, event_size: str | None = None,
               event_threshold: float = 0.2, rig: str | None = None, views: str | None = None,
               randomize: bool = False, classmap: str | None = None, executor: str = "local",
               workers: int | None = None, ray_address: str | None = None, pm=None,
               progress: Progress | None = None, param: list[str] | None = None) -> dict:
    """Render a dataset; returns the summary (also the basis of meta.json)."""
    from .executors import make_executor
    from .plugins import get_plugin_manager
    from .render import (Camera, DatasetWriter, EventSimulator, GroundSampler, Intrinsics, RenderParams,
                         StereoCamera, WEATHERS, build_render_mesh, lane_trajectory, load_poses_file,
                         parse_formats, sample_lane_poses, stage_lanes)
    from .render.classmap import load_class_map
    from .render.pipeline import FrameJob, RenderContext, forget, render_chunk
    from .render.rig_usd import read_stage_cameras, rig_preset
    from .usd.town_reader import load_town

    t0 = time.perf_counter()
    report = progress or (lambda *_: None)
    stage = Path(stage)
    from .usd.checks import output_path

    output_path(out, "dir")
    preset = rig_preset(rig) if rig is not None else None
    size_text = size if size is not None else (f"{preset.width}x{preset.height}" if preset else "640x480")
    width, height_px = parse_size(size_text)
    hfov = _pick(hfov, preset and preset.hfov_deg, 90.0)
    height = _pick(height, preset and preset.height_m, 1.5)
    pitch = _pick(pitch, preset and preset.pitch_deg, None)
    baseline = _pick(baseline, preset and preset.baseline_m, 0.54)
    stereo = bool(stereo or (preset is not None and preset.baseline_m))
    view_kind, share, background = parse_views(views)
    if poses is not None and view_kind != "none":
        raise RoadtwinError("give --poses or --views, not both")
    cmap = None
    if classmap is not None:
        spec = classmap[len("builtin:"):] if classmap.startswith("builtin:") else classmap
        cmap = load_class_map(spec)
    runner = make_executor(executor, ray_address, workers)
    if workers is not None and workers < 1:
        raise RoadtwinError(f"--workers must be >= 1, got {workers}")
    check_range("--frames", frames, 1, MAX_FRAMES)
    check_range("--seed", seed, 0, 2**63 - 1)
    check_range("--hfov", hfov, 1.0, 179.0, "degrees")
    check_range("--height", height, 1e-3, 1000.0, "m")
    if pitch is not None:
        check_range("--pitch", pitch, -89.0, 89.0, "degrees")
    if weather not in WEATHERS:
        raise RoadtwinError(f"unknown weather {weather!r} (known: {', '.join(WEATHERS)})")
    intr = Intrinsics.from_fov(width, height_px, hfov)
    if stereo:
        check_range("--baseline", baseline, 1e-3, 100.0, "m")
    ev_w, ev_h = parse_size(event_size, "--event-size") if event_size else (width, height_px)
    if events:
        check_range("--event-frames", event_frames, 2, MAX_FRAMES)
        check_range("--event-threshold", event_threshold, 1e-6, 100.0)
        check_range("--speed", speed, 1e-3, 200.0, "m/s")
        check_range("--event-rate", event_rate, 1e-3, 1e6, "Hz")
        try:
            import h5py  # noqa: F401
        except ImportError:
            raise RoadtwinError("--events writes HDF5 and needs h5py (pip install h5py)") from None
    params = check_params(RenderParams(weather=weather, seed=seed, device=device, backend=backend), "render")
    params = cli_params(param, params, f"renderer {renderer}")

    pm = pm or get_plugin_manager()
    rend = pm.get("renderers", renderer)
    if not stage.exists():
        raise RoadtwinError(f"{stage}: no such file")
    town = load_town(stage, looks=True, variants={"roadMaterial": material} if material else None)
    mesh = build_render_mesh(town, defect_types=pm.registry("defect_types").keys())
    if cmap is not None:
        cmap.check_labels(mesh.classes, str(stage))
    lanes = stage_lanes(stage)
    lane_width = float(town.metadata.get("laneWidthM", 3.5) or 3.5)
    ground = None

    def ground_fn():
        nonlocal ground
        if ground is None:
            ground = GroundSampler(mesh)
        return ground

    view_records: list[dict] = []
    chained = None
    lane_of: list = []                  # (lane, s) per frame for the ego lane, or None
    stage_cams = [] if (poses is not None or view_kind != "none") else read_stage_cameras(
        stage, (width, height_px) if size is not None else None)
    if preset is not None:
        stage_cams = [c for c in stage_cams if c.rig == preset.name]
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
    elif view_kind == "defects":
        from .render.view_sampler import ViewRig, chain_lanes, defect_targets, sample_views

        vrig = ViewRig(mount_height_m=height, hfov_deg=hfov, width_px=width, height_px=height_px,
                       **({"pitch_deg": pitch} if pitch is not None else {}))
        chained = chain_lanes(lanes)      # what view_sampler.stage_views does, without re-reading the stage
        if not chained:
            raise RoadtwinError(f"{stage}: no driving lane centrelines (roadtwin:segment:centerline) to place views on")
        sampled = sample_views(chained, defect_targets(town), ground_fn(), frames, rig=vrig, share=share, seed=seed,
                               background=background)
        by_id = {l.id: l for l in chained}
        pose_list = [v.cam_to_world for v in sampled]
        lane_of = [(by_id[v.lane_id], v.s_m) for v in sampled]
        view_records = [{k: v for k, v in view.as_dict().items() if k not in ("index", "cam_to_world")}
                        for view in sampled]
        pose_source = f"defects:{share}" + (":clear" if background == "clear" else "")
    elif stage_cams:
        sizes = {(c.intrinsics.width, c.intrinsics.height, round(c.intrinsics.fx, 6), round(c.intrinsics.fy, 6))
                 for c in stage_cams}
        if len(sizes) > 1:
            raise RoadtwinError(f"{stage}: its cameras differ in image size or focal length "
                                f"({', '.join(sorted({c.rig for c in stage_cams}))}); pick one rig with --rig")
        stage_cams = stage_cams[:frames]
        intr = stage_cams[0].intrinsics
        if stage_cams[0].baseline_m:
            stereo, baseline = True, stage_cams[0].baseline_m
        pose_list = [c.cam_to_world for c in stage_cams]
        view_records = [{"camera_prim": c.path, "rig": c.rig} for c in stage_cams]
        pose_source = "stage cameras"
    elif lanes:
        rng = np.random.default_rng(seed)
        kw = {}
        if preset is not None or pitch is not None:       # a rig: its pitch, small jitter
            p0 = pitch if pitch is not None else -15.0
            kw = {"pitch_deg": (p0 - 2.0, p0 + 2.0), "yaw_jitter_deg": 3.0, "roll_jitter_deg": 1.0}
        pose_list = sample_lane_poses(lanes, frames, rng, ground_fn(), height=height, **kw)
        pose_source = "lanes"
    else:
        raise RoadtwinError(f"{stage}: no cameras or poses: the stage has no driving lane centerlines "
                            "(roadtwin:segment:centerline), no camera prims and no --poses file was given")
    fmt = parse_formats(formats, stereo)
    cams = [Camera(intr, p) for p in pose_list]
    if stereo:
        cams = [StereoCamera(c, baseline) for c in cams]

    # the ego lane of frames not drawn by the view sampler: the chained lane the camera drives in
    if cmap is not None and cmap.ego and not lane_of:
        from .render.view_sampler import chain_lanes

        chained = chain_lanes(lanes)
        lane_of = [nearest_lane(chained, p, lane_width) for p in pose_list]
    if cmap is not None and cmap.ego:
        from .render.view_sampler import lane_ahead

        lane_xy = [lane_ahead(l, s) if l is not None else None for l, s in
                   ((x if x is not None else (None, 0.0)) for x in lane_of)]
    else:
        lane_xy = [None] * len(cams)

    table = None
    if randomize:
        from .render.randomize import Ranges, draw
        from .render.scene_look import LookTable

        r = Ranges()
        mesh, table = LookTable.split(mesh, stage.parent, tuple(r.verge_surfaces) + tuple(r.shoulder_surfaces)
                                         + ("pothole_wet",))
    jobs = []
    for i, cam in enumerate(cams):
        record: dict = {}
        if view_records:
            record["view"] = view_records[i]
        if lane_of and lane_of[i] is not None:
            record.setdefault("view", {})["ego_lane"] = {"lane": lane_of[i][0].id, "s_m": round(lane_of[i][1], 3)}
        if table is not None:
            fr = draw(seed, i, base=params)
            look = table.look(fr.look)
            record["randomization"] = {**fr.as_dict(), "applied": look.applied}
            jobs.append(FrameJob(i, cam, check_params(fr.render, "render"), look, fr.effects, lane_xy[i], record))
        else:
            jobs.append(FrameJob(i, cam, params, None, None, lane_xy[i], record))

    ctx = RenderContext(f"{os.getpid()}-{time.time_ns()}", rend, mesh, params, cmap, lane_width, "normal" in fmt)
    n_workers = 1 if runner.name == "serial" else (workers or os.cpu_count() or 1)
    per_chunk = max(1, min(16, -(-len(jobs) // (4 * n_workers)))) if runner.name != "serial" else 1
    chunks = [jobs[i:i + per_chunk] for i in range(0, len(jobs), per_chunk)]

    ev_iter = None
    if events:
        if not lanes:
            raise RoadtwinError(f"{stage}: --events drives along a lane, but the stage has no driving lane centerlines")
        prepared = rend.prepare(mesh, params)
        ev_times, ev_poses = lane_trajectory(lanes, np.random.default_rng([seed, 1]), ground_fn(), speed=speed,
                                             rate_hz=event_rate, n_frames=event_frames, height=height)
        ev_intr = Intrinsics.from_fov(ev_w, ev_h, hfov)
        ev_iter = rend.render(prepared, [Camera(ev_intr, p) for p in ev_poses], dataclasses.replace(params, shade=True))
    t_setup = time.perf_counter()

    classes = list(cmap.classes) if cmap is not None else mesh.classes
    shares: list[dict] = []
    with atomic_output_dir(out) as tmp:
        writer = DatasetWriter(tmp, fmt, intr, classes, mesh.instances, baseline if stereo else None,
                               categories=mesh.defect_types)
        done = 0
        backend_used = device_used = None
        try:
            for outs in runner.imap(render_chunk, ctx, chunks):
                for fo in outs:
                    backend_used, device_used = fo.backend, fo.device
                    writer.add(fo.frame, fo.rgb8, fo.image_bytes, fo.rgb8_right, fo.image_bytes_right,
                               {**jobs[done].record, "defect_share": {k: round(v, 6) for k, v in fo.defect_share.items()}})
                    shares.append(fo.defect_share)
                    done += 1
                    report("render", done, len(jobs))
        finally:
            forget(ctx.token)
        t_frames = time.perf_counter()
        n_events = 0
        if ev_iter is not None:
            # a renderer that keeps frames on a GPU simulates the events there (same events)
            got = rend.render_events(prepared, [Camera(ev_intr, p) for p in ev_poses], ev_times, params,
                                     progress=lambda k, n: report("events", k, n), threshold=event_threshold,
                                     seed=seed)
            if got is None:
                sim = EventSimulator(ev_w, ev_h, threshold=event_threshold, seed=seed)
                ev_chunks = []
                for k, (frame, t) in enumerate(zip(ev_iter, ev_times)):
                    ev_chunks.append(sim.step(frame.rgb, float(t)))
                    report("events", k + 1, len(ev_times))
                ev = {key: np.concatenate([c[key] for c in ev_chunks]) for key in ("x", "y", "t", "p")}
                got = ev, sim.params()
            ev, sim_params = got
            n_events = len(ev["t"])
            writer.write_events(ev, ev_times, ev_poses, (ev_w, ev_h),
                                {**sim_params, "speed_mps": speed, "rate_hz": event_rate})
        t_events = time.perf_counter()
        summary = {
            "stage": str(stage), "renderer": renderer, "frames": len(cams), "size": [intr.width, intr.height],
            "stereo": bool(stereo), "formats": fmt, "events": n_events, "poses": pose_source,
            "rig": preset.name if preset else None, "hfov_deg": round(float(np.degrees(2 * np.arctan(
                intr.width / 2 / intr.fx))), 4), "randomize": bool(randomize),
            "class_map": None if cmap is None else {"name": cmap.name, "source": cmap.source,
                                                    "classes": list(cmap.classes), "stage_labels": mesh.classes},
            "executor": runner.name, "backend": backend_used, "device": device_used,
            "defects": defect_statistics(shares),
            "render_params": dataclasses.asdict(params), "material": material, "seed": seed,
            "timings_s": {"setup": round(t_setup - t0, 3), "frames": round(t_frames - t_setup, 3),
                          "events": round(t_events - t_frames, 3)},
        }
        summary["frames_per_s"] = round(len(cams) / max(t_frames - t_setup, 1e-9), 3)
        writer.finish({"render": summary})
    return summary


def defect_statistics(shares: list[dict]) -> dict:
    """Share of frames with pothole / crack pixels and their mean pixel shares: whether the
    frames show defects at all (random views of a sparse road mostly do not)."""
    out = {}
    for c in ("pothole", "crack"):
        v = np.array([s[c] for s in shares if c in s])
        if len(v):
            out[c] = {"frames_with": round(float((v > 0).mean()), 4), "mean_pixel_share": round(float(v.mean()), 6),
                      "mean_pixel_share_when_present": round(float(v[v > 0].mean()), 6) if (v > 0).any() else 0.0}
    return out


def render(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    frames: int = typer.Option(8, "--frames", help="number of frames (with --poses or stage cameras: at most theirs)"),
    rig: Optional[str] = typer.Option(None, "--rig", help="camera rig preset: survey | dashcam | stereo | inspection "
                                      "(size, field of view, height, pitch, baseline; explicit options override)"),
    views: Optional[str] = typer.Option(None, "--views", help="random (lane poses) | defects:SHARE[:clear] (that share "
                                        "of frames aimed at a pothole or crack 5-25 m ahead; :clear = the rest "
                                        "without any). Default: the stage's camera prims, else random"),
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
    executor: str = typer.Option("local", "--executor", help="local (process pool) | serial | ray"),
    workers: Optional[int] = typer.Option(None, "--workers", help="worker processes (default: all cores)"),
    ray_address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster address (default: a local one)"),
    speed: float = typer.Option(8.0, "--speed", help="event drive speed in m/s"),
    event_rate: float = typer.Option(500.0, "--event-rate", help="event drive frame rate in Hz"),
    event_frames: int = typer.Option(50, "--event-frames", help="frames rendered for the event camera"),
    event_size: Optional[str] = typer.Option(None, "--event-size", help="event camera size (default: --size)"),
    event_threshold: float = typer.Option(0.2, "--event-threshold", help="mean log-intensity contrast threshold"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"renderer {PARAM_HELP}"),
) -> None:
    """Render RGB, labels, depth, normals, stereo and events from a composed town."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress as Bar, TextColumn, TimeElapsedColumn

    from ._console import err_console

    with Bar(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
             console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        tasks: dict[str, int] = {}

        def report(what: str, done: int, total: int) -> None:
            if what not in tasks:
                tasks[what] = bar.add_task(f"{what} frames", total=total)
            bar.update(tasks[what], completed=done)

        summary = run_render(stage, out, frames=frames, size=size, stereo=stereo, baseline=baseline, events=events,
                             formats=formats, seed=seed, hfov=hfov, height=height, pitch=pitch, poses=poses,
                             weather=weather, material=material, renderer=renderer, device=device, backend=backend,
                             speed=speed, event_rate=event_rate, event_frames=event_frames, event_size=event_size,
                             event_threshold=event_threshold, rig=rig, views=views, randomize=randomize,
                             classmap=classmap, executor=executor, workers=workers, ray_address=ray_address,
                             progress=report, param=param)
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


rig_app = typer.Typer(add_completion=False, no_args_is_help=True,
                      help="camera rigs as UsdGeom.Camera prims in a stage (used by roadtwin render)")


@rig_app.command("add")
def rig_add(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    rig: str = typer.Option("survey", "--rig", help="comma-separated presets: survey,dashcam,stereo,inspection"),
    at_s: float = typer.Option(20.0, "--at-s", help="default pose: metres along the stage's first driving lane"),
) -> None:
    """Write camera prims for rig presets into layers/cameras.usda (the stage's strongest sublayer)."""
    from .render.rig_usd import add_rig_cameras, read_stage_cameras

    names = [r.strip() for r in rig.split(",") if r.strip()]
    layer = add_rig_cameras(stage, names, at_s=at_s)
    table = Table(title=f"cameras in {layer}")
    for col in ("prim", "rig", "size", "fx (px)", "position (m)"):
        table.add_column(col)
    for c in read_stage_cameras(stage):
        k = c.intrinsics
        table.add_row(c.path, c.rig, f"{k.width}x{k.height}", f"{k.fx:.1f}",
                      ", ".join(f"{x:.2f}" for x in c.cam_to_world[:3, 3]))
    console.print(table)
