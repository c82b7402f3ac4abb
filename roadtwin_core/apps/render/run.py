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
import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ...atomic import atomic_output_dir
from ...errors import RoadtwinError
from ...params import check_params, cli_params
from .lanes import nearest_lane
from .options import MAX_FRAMES, check_range, parse_size, parse_views, pick

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
    """Render a dataset; returns the summary (also the basis of meta.json)."""
    from ...executors import make_executor
    from ...plugins import get_plugin_manager
    from ...render import (Camera, EventSimulator, GroundSampler, Intrinsics, RenderParams, StereoCamera, WEATHERS,
                           build_render_mesh, lane_trajectory, load_poses_file, sample_lane_poses, stage_lanes)
    from ...render.classmap import load_class_map
    from ...render.rig_usd import read_stage_cameras, rig_preset
    from ...usd.town_reader import load_town
    from .pipeline import FrameJob, RenderContext, forget, render_chunk
    from .writers import DatasetWriter, parse_formats

    t0 = time.perf_counter()
    report = progress or (lambda *_: None)
    stage = Path(stage)
    from ...atomic import output_path

    output_path(out, "dir")
    preset = rig_preset(rig) if rig is not None else None
    size_text = size if size is not None else (f"{preset.width}x{preset.height}" if preset else "640x480")
    width, height_px = parse_size(size_text)
    hfov = pick(hfov, preset and preset.hfov_deg, 90.0)
    height = pick(height, preset and preset.height_m, 1.5)
    pitch = pick(pitch, preset and preset.pitch_deg, None)
    baseline = pick(baseline, preset and preset.baseline_m, 0.54)
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
        from ...render.view_sampler import ViewRig, chain_lanes, defect_targets, sample_views

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
        from ...render.view_sampler import chain_lanes

        chained = chain_lanes(lanes)
        lane_of = [nearest_lane(chained, p, lane_width) for p in pose_list]
    if cmap is not None and cmap.ego:
        from ...render.view_sampler import lane_ahead

        lane_xy = [lane_ahead(l, s) if l is not None else None for l, s in
                   ((x if x is not None else (None, 0.0)) for x in lane_of)]
    else:
        lane_xy = [None] * len(cams)

    table = None
    if randomize:
        from ...render.randomize import Ranges, draw
        from ...render.scene_look import LookTable

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
