"""``run_render``: synthetic perception data from a composed town (what ``roadtwin render`` does).

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
The renderer is a plugin, found by name (``--renderer``, default ``warp``). Workers run
``pipeline.render_chunk``; the main process only writes (``writers``).
"""
from __future__ import annotations

import dataclasses
import functools
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ...atomic import atomic_output_dir
from ...errors import RoadtwinError
from ...params import check_params, cli_params
from .cameras import CameraPlan, ego_lane_points, plan_cameras, with_ego_lanes
from .options import MAX_FRAMES, Rig, check_range, check_rig, parse_size, parse_views, resolve_rig
from .pipeline import FrameJob, RenderContext, forget, render_chunk
from .writers import DatasetWriter, available_formats, parse_formats

__all__ = ["Progress", "defect_statistics", "run_render"]

Progress = Callable[[str, int, int], None]


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
    """Render a dataset; returns the summary (also the basis of meta.json). Everything is checked
    and the cameras are chosen before the output directory is touched."""
    from ...atomic import output_path
    from ...executors import make_executor
    from ...plugins import get_plugin_manager
    from ...render import GroundSampler, Intrinsics, RenderParams, WEATHERS, build_render_mesh, stage_lanes
    from ...render.classmap import load_class_map
    from ...usd.town_reader import load_town

    t0 = time.perf_counter()
    stage = Path(stage)
    output_path(out, "dir")
    r = resolve_rig(rig, size, hfov, height, pitch, baseline, stereo)
    view_kind, share, background = parse_views(views)
    if poses is not None and view_kind != "none":
        raise RoadtwinError("give --poses or --views, not both")
    cmap = None
    if classmap is not None:
        cmap = load_class_map(classmap[len("builtin:"):] if classmap.startswith("builtin:") else classmap)
    runner = make_executor(executor, ray_address, workers)
    if workers is not None and workers < 1:
        raise RoadtwinError(f"--workers must be >= 1, got {workers}")
    check_range("--frames", frames, 1, MAX_FRAMES)
    check_range("--seed", seed, 0, 2**63 - 1)
    check_rig(r)
    if weather not in WEATHERS:
        raise RoadtwinError(f"unknown weather {weather!r} (known: {', '.join(WEATHERS)})")
    drive = _check_events(events, event_size, event_frames, event_threshold, speed, event_rate, r)
    params = check_params(RenderParams(weather=weather, seed=seed, device=device, backend=backend), "render")
    params = cli_params(param, params, f"renderer {renderer}")  # --param KEY=VALUE

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
    ground = functools.lru_cache(maxsize=1)(lambda: GroundSampler(mesh))   # built once, if a camera needs it
    plan = plan_cameras(stage, town, lanes, ground, r, Intrinsics.from_fov(r.width, r.height_px, r.hfov_deg),
                        frames=frames, poses=poses, view_kind=view_kind, share=share, background=background,
                        seed=seed, min_clearance_m=params.min_clearance_m)
    known_formats = available_formats(pm.registry("dataset_formats"))
    fmt = parse_formats(formats, plan.stereo, known_formats)
    if cmap is not None and cmap.ego:
        plan = with_ego_lanes(plan, lanes, lane_width)
        lane_xy = ego_lane_points(plan)
    else:
        lane_xy = [None] * len(plan.poses)
    mesh, jobs = frame_jobs(plan, mesh, params, stage, seed, lane_xy, randomize)
    ctx = RenderContext(f"{os.getpid()}-{time.time_ns()}", rend, mesh, params, cmap, lane_width, "normal" in fmt)
    if drive is not None:
        if not lanes:
            raise RoadtwinError(f"{stage}: --events drives along a lane, but the stage has no driving lane centerlines")
        drive = drive.start(rend, mesh, params, lanes, ground(), seed, r)
    t_setup = time.perf_counter()

    classes = list(cmap.classes) if cmap is not None else mesh.classes
    with atomic_output_dir(out) as tmp:
        writer = DatasetWriter(tmp, fmt, plan.intrinsics, classes, mesh.instances,
                               plan.baseline_m if plan.stereo else None, categories=mesh.defect_types,
                               available=known_formats)
        shares, backend_used, device_used = _render_frames(runner, ctx, jobs, writer, workers, progress)
        t_frames = time.perf_counter()
        n_events = drive.write(writer, progress) if drive is not None else 0
        t_events = time.perf_counter()
        intr = plan.intrinsics
        summary = {
            "stage": str(stage), "renderer": renderer, "frames": len(plan.poses), "size": [intr.width, intr.height],
            "stereo": bool(plan.stereo), "formats": fmt, "events": n_events, "poses": plan.source,
            "rig": r.preset.name if r.preset else None, "hfov_deg": round(float(np.degrees(2 * np.arctan(
                intr.width / 2 / intr.fx))), 4), "randomize": bool(randomize),
            "class_map": None if cmap is None else {"name": cmap.name, "source": cmap.source,
                                                    "classes": list(cmap.classes), "stage_labels": mesh.classes},
            "executor": runner.name, "backend": backend_used, "device": device_used,
            "defects": defect_statistics(shares),
            "render_params": dataclasses.asdict(params), "material": material, "seed": seed,
            "timings_s": {"setup": round(t_setup - t0, 3), "frames": round(t_frames - t_setup, 3),
                          "events": round(t_events - t_frames, 3)},
        }
        summary["frames_per_s"] = round(len(plan.poses) / max(t_frames - t_setup, 1e-9), 3)
        writer.finish({"render": summary})
    return summary


def frame_jobs(plan: CameraPlan, mesh, params, stage: Path, seed: int, lane_xy: list, randomize: bool):
    """(mesh, one FrameJob per camera). With ``randomize`` each frame draws its look and camera
    model from (seed, i) alone, so every executor renders the same frames; the mesh then gets the
    look table's split materials."""
    from ...render import Camera, StereoCamera

    cams = [Camera(plan.intrinsics, p) for p in plan.poses]
    if plan.stereo:
        cams = [StereoCamera(c, plan.baseline_m) for c in cams]
    table = None
    if randomize:
        from ...render.randomize import Ranges, draw
        from ...render.scene_look import LookTable

        ranges = Ranges()
        mesh, table = LookTable.split(mesh, stage.parent, tuple(ranges.verge_surfaces) + tuple(ranges.shoulder_surfaces)
                                      + ("pothole_wet",))
    jobs = []
    for i, cam in enumerate(cams):
        record: dict = {}
        if plan.view_records:
            record["view"] = plan.view_records[i]
        if plan.lane_of and plan.lane_of[i] is not None:
            lane, s = plan.lane_of[i]
            record.setdefault("view", {})["ego_lane"] = {"lane": lane.id, "s_m": round(s, 3)}
        if table is not None:
            fr = draw(seed, i, base=params)
            look = table.look(fr.look)
            record["randomization"] = {**fr.as_dict(), "applied": look.applied}
            jobs.append(FrameJob(i, cam, check_params(fr.render, "render"), look, fr.effects, lane_xy[i], record))
        else:
            jobs.append(FrameJob(i, cam, params, None, None, lane_xy[i], record))
    return mesh, jobs


def _render_frames(runner, ctx: RenderContext, jobs: list, writer, workers: int | None, progress: Progress | None):
    """Frames rendered in chunks on the executor's workers, written here in frame order;
    returns (per-frame defect pixel shares, backend, device)."""
    report = progress or (lambda *_: None)
    n_workers = 1 if runner.name == "serial" else (workers or os.cpu_count() or 1)
    per_chunk = max(1, min(16, -(-len(jobs) // (4 * n_workers)))) if runner.name != "serial" else 1
    chunks = [jobs[i:i + per_chunk] for i in range(0, len(jobs), per_chunk)]
    shares: list[dict] = []
    backend_used = device_used = None
    try:
        for outs in runner.imap(render_chunk, ctx, chunks):
            for fo in outs:
                backend_used, device_used = fo.backend, fo.device
                writer.add(fo.frame, fo.rgb8, fo.image_bytes, fo.rgb8_right, fo.image_bytes_right,
                           {**jobs[len(shares)].record,
                            "defect_share": {k: round(v, 6) for k, v in fo.defect_share.items()}})
                shares.append(fo.defect_share)
                report("render", len(shares), len(jobs))
    finally:
        forget(ctx.token)
    return shares, backend_used, device_used


def _check_events(events: bool, event_size, event_frames, event_threshold, speed, event_rate, r: Rig):
    """--events' options checked; the drive to simulate, or None without --events."""
    ev_w, ev_h = parse_size(event_size, "--event-size") if event_size else (r.width, r.height_px)
    if not events:
        return None
    check_range("--event-frames", event_frames, 2, MAX_FRAMES)
    check_range("--event-threshold", event_threshold, 1e-6, 100.0)
    check_range("--speed", speed, 1e-3, 200.0, "m/s")
    check_range("--event-rate", event_rate, 1e-3, 1e6, "Hz")
    try:
        import h5py  # noqa: F401
    except ImportError:
        raise RoadtwinError("--events writes HDF5 and needs h5py (pip install h5py)") from None
    return EventDrive((ev_w, ev_h), event_frames, event_threshold, speed, event_rate)


@dataclass
class EventDrive:
    """``--events``: a continuous drive along one lane, its frames fed to the event camera (on the
    renderer's device when it can simulate there, else by the core's simulator from the frames)."""

    size: tuple[int, int]
    n_frames: int
    threshold: float
    speed: float
    rate_hz: float
    _run: tuple | None = None

    def start(self, rend, mesh, params, lanes, ground, seed: int, r: Rig) -> "EventDrive":
        from ...render import Camera, Intrinsics, lane_trajectory

        prepared = rend.prepare(mesh, params)
        times, poses = lane_trajectory(lanes, np.random.default_rng([seed, 1]), ground, speed=self.speed,
                                       rate_hz=self.rate_hz, n_frames=self.n_frames, height=r.mount_height_m)
        cams = [Camera(Intrinsics.from_fov(*self.size, r.hfov_deg), p) for p in poses]
        frames = rend.render(prepared, cams, dataclasses.replace(params, shade=True))
        self._run = (rend, prepared, cams, times, poses, params, seed, frames)
        return self

    def write(self, writer, progress: Progress | None) -> int:
        """Simulate the events and write them; their count."""
        from ...render import EventSimulator

        report = progress or (lambda *_: None)
        rend, prepared, cams, times, poses, params, seed, frames = self._run
        got = rend.render_events(prepared, cams, times, params, progress=lambda k, n: report("events", k, n),
                                 threshold=self.threshold, seed=seed)
        if got is None:
            sim = EventSimulator(*self.size, threshold=self.threshold, seed=seed)
            parts = []
            for k, (frame, t) in enumerate(zip(frames, times)):
                parts.append(sim.step(frame.rgb, float(t)))
                report("events", k + 1, len(times))
            got = {key: np.concatenate([c[key] for c in parts]) for key in ("x", "y", "t", "p")}, sim.params()
        ev, sim_params = got
        writer.write_events(ev, times, poses, self.size, {**sim_params, "speed_mps": self.speed, "rate_hz": self.rate_hz})
        return len(ev["t"])


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
