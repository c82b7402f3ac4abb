"""``run_render``: synthetic perception data from a composed town (what ``roadtwin render`` does).

    roadtwin render out/town/town.usda --frames 100 --size 640x480 --stereo --events \\
        --formats kitti,mmseg,coco,depth,normal -o out/render
    roadtwin render out/highway/town.usda --rig survey --views defects:0.6 --randomize \\
        --classmap builtin:road_defects_br --frames 2000 --executor local -o out/survey

Appearance is the stage's: the UsdPreviewSurface materials and textures bound to its meshes
(``--material`` only picks a variant of the root's ``roadMaterial`` variant set, in memory).
Cameras, first that applies: a ``--poses`` JSON file; ``--views defects:SHARE[:clear][:NEAR-FAR]`` (the
view sampler: that share of frames aimed at a pothole or crack NEAR-FAR m ahead, default 5-25, the
rest along the lanes) or ``--views random`` (random lane poses, ``--height`` m above the road, yaw / pitch / roll
jitter); the stage's ``UsdGeom.Camera`` prims (``roadtwin rig add``); random lane poses.
``--rig`` sets size, field of view, height, pitch and stereo baseline from a preset
(``cameras.RIG_PRESETS``); explicit ``--size/--hfov/--height/--pitch/--baseline`` override it.
``--randomize`` draws per frame (``randomize.draw(seed, i)``) the sun, sky, weather, road tint and
wear, verge and shoulder surfaces (applied by the renderer, ``scene_look``) and a camera model
(``apply_sensor``: blur, vignetting, exposure, noise, white balance, JPEG; images are the JPEG
bytes); labels are untouched. ``--classmap`` maps the labels to a dataset's classes with the
frame's ego lane (``ego_lane``) and grows thin classes (``[dilate_px]``). Frames are rendered in
chunks on ``--executor`` (local pool, serial, Ray; Ray with a CUDA ``--device``: one shard of
frames a GPU of the cluster, ``gpu_shards``); frame i depends only on (seed, i), so every
executor writes the same bytes (on the same kind of device). ``--events`` adds a continuous drive along one lane (``--speed``
m/s, ``--event-rate`` Hz, ``--event-frames`` frames) fed to the event camera simulator.
Everything is checked before the output directory is touched (size, formats, weather, renderer,
stage, poses, rig, views, class map) and the directory is written whole or not at all.
The renderer is a plugin, found by name (``--renderer``, default ``warp``). On the CPU, worker
processes run ``pipeline.render_chunk``; on a GPU device (and with ``--executor serial``) frames
render in this process while ``--workers`` processes (GPU) or threads (serial) finish and write
them (``frame_sink``: the camera model, labels and file encoding are the CPU's share of a GPU
render; a renderer with ``render_finished`` runs the camera model and the ego-lane labels on a
CUDA device instead, ``device_frames``: other noise bytes than the CPU's, same seed same bytes);
frames are recorded in order either way. ``phase_timings_s`` in the summary sums each phase's seconds.

A run has four parts: the options checked (:func:`check_options`), the scene loaded
(:func:`load_scene`), the frames planned (:func:`plan_frames`: cameras, formats, what decides each
frame's job), then the dataset rendered and written (:func:`write_dataset`: the jobs planned, on a
GPU by the forked finishing processes while the scene uploads, the event drive, the frames).
"""
from __future__ import annotations

import dataclasses
import functools
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ...atomic import atomic_output_dir, output_path
from ...errors import RoadtwinError
from ...executors import make_executor
from ...params import apply_params, check_params
from ...plugins import get_plugin_manager
from ...render import (WEATHERS, GroundSampler, Intrinsics, RenderParams, build_render_mesh,
                       stage_lanes)
from ...render.classmap import load_class_map
from ...render.randomize import Ranges
from ...render.view_sampler import chain_lanes
from ...render.scene_look import LookTable
from ...warp_runtime import warp_device
from .cameras import CameraPlan, DefectViews, plan_cameras
from .events import EventDrive, check_events
from . import gpu_shards
from .options import MAX_FRAMES, RenderOptions, Rig, ViewSpec, check_range, check_rig, parse_views, resolve_rig
from .frame_sink import FrameSink, render_in_process
from .pipeline import RenderContext, forget, prepared_scene, render_chunk
from .planning import FramePlanner, forking, plan_all
from .writers import DatasetWriter, available_formats, parse_formats

__all__ = ["CheckedOptions", "FramePlan", "Progress", "RenderOptions", "Scene", "check_options", "defect_statistics",
           "load_scene", "plan_frames", "run_render", "write_dataset"]

Progress = Callable[[str, int, int], None]


def run_render(stage: str | Path, out: str | Path, options: RenderOptions | None = None, *, pm=None,
               progress: Progress | None = None) -> dict:
    """Render a dataset; returns the summary (also the basis of meta.json). Everything is checked
    and the cameras are chosen before the output directory is touched."""
    o = options or RenderOptions()
    t0 = time.perf_counter()
    stage = Path(stage)
    output_path(out, "dir")
    checked = check_options(o)
    pm = pm or get_plugin_manager()
    scene = load_scene(stage, o, checked, pm)
    frames = plan_frames(stage, o, checked, scene, pm)
    with atomic_output_dir(out) as tmp:
        return write_dataset(tmp, stage, o, checked, scene, frames, progress, t0)


@dataclass
class CheckedOptions:
    """The options checked, and what they resolve to."""

    rig: Rig
    views: ViewSpec                # --views
    class_map: Any                 # classmap.ClassMap or None
    runner: Any                    # the executor
    drive: EventDrive | None       # --events
    params: RenderParams           # --weather/--seed/--device/--backend and the renderer's --param values
    ranges: Ranges = field(default_factory=Ranges)   # --randomize's ranges (the class map's camera targets)


def check_options(o: RenderOptions) -> CheckedOptions:
    """Every option checked (one line naming the option), before any file is read but the class map."""
    r = resolve_rig(o.rig, o.size, o.hfov, o.height, o.pitch, o.baseline, o.stereo)
    views = parse_views(o.views)
    if o.poses is not None and views.kind != "none":
        raise RoadtwinError("give --poses or --views, not both")
    cmap = None
    if o.classmap is not None:
        cmap = load_class_map(o.classmap[len("builtin:"):] if o.classmap.startswith("builtin:") else o.classmap)
    runner = make_executor(o.executor, o.ray_address, o.workers)
    if o.workers is not None and o.workers < 1:
        raise RoadtwinError(f"--workers must be >= 1, got {o.workers}")
    check_range("--frames", o.frames, 1, MAX_FRAMES)
    check_range("--seed", o.seed, 0, 2**63 - 1)
    check_rig(r)
    if o.weather not in WEATHERS:
        raise RoadtwinError(f"unknown weather {o.weather!r} (known: {', '.join(WEATHERS)})")
    drive = check_events(o, r)
    params = check_params(RenderParams(weather=o.weather, seed=o.seed, device=o.device, backend=o.backend), "render")
    params = apply_params(params, o.renderer_params, f"renderer {o.renderer}")
    # a class map may name camera targets measured from its dataset's real frames (--randomize)
    ranges = Ranges.from_targets(cmap.camera_targets) if o.randomize and cmap is not None and cmap.camera_targets \
        else Ranges()
    return CheckedOptions(r, views, cmap, runner, drive, params, ranges)


@dataclass
class Scene:
    """The town to render: the renderer plugin, the town read from the stage, its render mesh and
    driving lanes; ``ground`` builds the ground sampler once, if a camera needs it."""

    renderer: Any
    town: Any
    mesh: Any
    lanes: list
    lane_width: float
    ground: Callable[[], GroundSampler]
    phases: dict = field(default_factory=dict)   # seconds: stage_read


def load_scene(stage: Path, o: RenderOptions, checked: CheckedOptions, pm) -> Scene:
    """The renderer and the stage (its ``--material`` variant) as a render mesh, with its lanes."""
    from ...usd.town_reader import load_town   # pxr: Ray render workers import apps.render, may have no USD

    t0 = time.perf_counter()
    rend = pm.get("renderers", o.renderer)
    if not stage.exists():
        raise RoadtwinError(f"{stage}: no such file")
    town = load_town(stage, looks=True, variants={"roadMaterial": o.material} if o.material else None)
    mesh = build_render_mesh(town, defect_types=pm.registry("defect_types").keys())
    if checked.class_map is not None:
        checked.class_map.check_labels(mesh.classes, str(stage))
    lanes = stage_lanes(stage)
    lane_width = float(town.metadata.get("laneWidthM", 3.5) or 3.5)
    ground = functools.lru_cache(maxsize=1)(lambda: GroundSampler(mesh))
    return Scene(rend, town, mesh, lanes, lane_width, ground, {"stage_read": time.perf_counter() - t0})


@dataclass
class FramePlan:
    """What will be rendered: the cameras, the formats, the planner of each frame's job (on
    ``mesh``, which ``--randomize`` gives the look table's split materials), what workers share."""

    cameras: CameraPlan | DefectViews
    formats: list[str]
    known_formats: Any
    mesh: Any
    planner: FramePlanner
    context: RenderContext
    phases: dict = field(default_factory=dict)   # seconds: stage_read, cameras


def plan_frames(stage: Path, o: RenderOptions, checked: CheckedOptions, scene: Scene, pm) -> FramePlan:
    """Cameras chosen, formats checked, and what decides each frame's job (``planning``: run by
    :func:`write_dataset`, on forked processes when there are many frames)."""
    r, cmap, params = checked.rig, checked.class_map, checked.params
    t0 = time.perf_counter()
    mesh, table = scene.mesh, None
    with ThreadPoolExecutor(1, thread_name_prefix="look-table") as side:
        # --randomize: the look table's variant textures decode while the cameras are chosen and the
        # ground sampler is built (PNG decoding and numpy let go of the GIL)
        surfaces = tuple(checked.ranges.verge_surfaces) + tuple(checked.ranges.shoulder_surfaces) + ("pothole_wet",)
        split = side.submit(LookTable.split, mesh, stage.parent, surfaces) if o.randomize else None
        cameras = plan_cameras(stage, scene.town, scene.lanes, scene.ground, r,
                               Intrinsics.from_fov(r.width, r.height_px, r.hfov_deg), frames=o.frames, poses=o.poses,
                               views=checked.views, seed=o.seed, min_clearance_m=params.min_clearance_m)
        known_formats = available_formats(pm.registry("dataset_formats"))
        fmt = parse_formats(o.formats, cameras.stereo, known_formats)
        if split is not None:
            mesh, table = split.result()
    chained = None
    if cmap is not None and cmap.ego:        # the view sampler's chained lanes where it chained them
        chained = cameras.chained if isinstance(cameras, DefectViews) else chain_lanes(scene.lanes)
    if checked.drive is not None and not scene.lanes:
        raise RoadtwinError(f"{stage}: --events drives along a lane, but the stage has no driving lane centerlines")
    planner = FramePlanner(cameras, params, o.seed, table, checked.ranges, chained, scene.lane_width)
    ctx = RenderContext(f"{os.getpid()}-{time.time_ns()}", scene.renderer, mesh, params, cmap, scene.lane_width,
                        "normal" in fmt)
    return FramePlan(cameras, fmt, known_formats, mesh, planner, ctx,
                     {**scene.phases, "cameras": time.perf_counter() - t0})


def write_dataset(folder: Path, stage: Path, o: RenderOptions, checked: CheckedOptions, scene: Scene,
                  frames: FramePlan, progress: Progress | None, started: float) -> dict:
    """Plan each frame's job, render the frames (and the events) into ``folder``, then meta.json;
    returns the summary. ``started``: when the run began (``time.perf_counter``).

    On a GPU the finishing processes are forked first (before the device is touched), plan the
    frames' blocks, and this process uploads the scene meanwhile."""
    cams, mesh, cmap, ctx = frames.cameras, frames.mesh, checked.class_map, frames.context
    classes = list(cmap.classes) if cmap is not None else mesh.classes
    writer = DatasetWriter(folder, frames.formats, cams.intrinsics, classes, mesh.instances,
                           cams.baseline_m if cams.stereo else None, categories=mesh.defect_types,
                           available=frames.known_formats)
    runner = checked.runner

    def upload() -> None:            # this process renders: its scene goes to the device meanwhile
        sink.phases["prepare"] = prepared_scene(ctx)[1]

    with forking(frames.planner):
        sink, mode = _open_sink(runner, ctx, writer, cams, o.workers, progress)
        try:
            t0 = time.perf_counter()
            plan, jobs, phases = plan_all(frames.planner, cams.frames, meanwhile=upload if mode == "here" else None,
                                          pool=sink.pool if sink.processes else None)
            sink.expect(jobs)
            sink.phases.update(phases, planning=time.perf_counter() - t0)
            drive = checked.drive
            if drive is not None:
                drive = drive.start(scene.renderer, mesh, checked.params, scene.lanes, scene.ground(), o.seed,
                                    checked.rig)
            t_setup = time.perf_counter()
            _render_frames(mode, runner, ctx, jobs, sink, o.workers)
            sink.close()
        finally:
            sink.shutdown()
            forget(ctx.token)
    shares, backend_used, device_used = sink.shares, sink.backend, sink.device
    t_frames = time.perf_counter()
    n_events = drive.write(writer, progress) if drive is not None else 0
    t_events = time.perf_counter()
    intr = plan.intrinsics
    summary = {
        "stage": str(stage), "renderer": o.renderer, "frames": len(plan.poses), "size": [intr.width, intr.height],
        "stereo": bool(plan.stereo), "formats": frames.formats, "events": n_events, "poses": plan.source,
        "rig": checked.rig.preset.name if checked.rig.preset else None, "hfov_deg": round(float(np.degrees(2 * np.arctan(
            intr.width / 2 / intr.fx))), 4), "randomize": bool(o.randomize),
        "class_map": None if cmap is None else {"name": cmap.name, "source": cmap.source,
                                                "classes": list(cmap.classes), "stage_labels": mesh.classes},
        "executor": runner.name, "backend": backend_used, "device": device_used,
        "defects": defect_statistics(shares),
        "render_params": dataclasses.asdict(checked.params), "material": o.material, "seed": o.seed,
        "timings_s": {"setup": round(t_setup - started, 3), "frames": round(t_frames - t_setup, 3),
                      "events": round(t_events - t_frames, 3)},
        # seconds per phase, summed over threads and workers (bench/render_throughput.py prints them)
        "phase_timings_s": {k: round(v, 4) for k, v in {**frames.phases, **sink.phases}.items()},
    }
    summary["frames_per_s"] = round(len(plan.poses) / max(t_frames - t_setup, 1e-9), 3)
    if sink.shards:        # --executor ray on GPUs: frames and card of each shard (gpu_shards)
        summary["shards"] = sink.shards
    writer.finish({"render": summary})
    return summary


def _open_sink(runner, ctx: RenderContext, writer, cameras, workers: int | None,
               progress: Progress | None) -> tuple[FrameSink, str]:
    """The frame sink (``frame_sink``) and where frames render: "here" (a GPU device: this process
    renders, ``workers`` forked processes, default one a core but this one, finish and write; the
    serial executor: ``workers`` threads, default 1), "shards" (Ray on a GPU device: one shard a
    GPU of the cluster, ``gpu_shards``, threads write the frames as they come) or "chunks" (on the
    CPU: chunks go to the executor's workers and come back finished, threads write them)."""
    report = progress or (lambda *_: None)
    n_cpu = os.cpu_count() or 1
    gpu = runner.name == "local" and _on_gpu(ctx.params.device)
    if gpu or runner.name == "serial":
        return FrameSink(ctx, writer, cameras, workers or (max(1, n_cpu - 1) if gpu else 1), gpu, report), "here"
    if runner.name == "ray" and gpu_shards.on_gpus(ctx.params.device):
        return FrameSink(ctx, writer, cameras, max(2, min(8, n_cpu)), False, report), "shards"
    return FrameSink(ctx, writer, cameras, min(4, n_cpu), False, report), "chunks"


def _render_frames(mode: str, runner, ctx: RenderContext, jobs: list, sink: FrameSink, workers: int | None) -> None:
    """Frames rendered (``mode``: :func:`_open_sink`'s) and handed to the sink, in order."""
    if mode == "shards":
        gpu_shards.render_on_gpus(runner, ctx, jobs, sink)
    elif mode == "here":
        render_in_process(ctx, jobs, sink)
    else:
        n_workers = workers or os.cpu_count() or 1
        per_chunk = max(1, min(16, -(-len(jobs) // (4 * n_workers))))
        chunks = [jobs[i:i + per_chunk] for i in range(0, len(jobs), per_chunk)]
        for outs in runner.imap(render_chunk, ctx, chunks):
            for fo in outs:
                sink.put(fo)


def _on_gpu(device: str | None) -> bool:
    """Whether the renderer's device is a GPU (a process pool would fork CUDA contexts: no)."""
    if device is not None:
        return str(device).startswith("cuda")
    try:
        return bool(warp_device(None).is_cuda)
    except Exception:
        return False


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
