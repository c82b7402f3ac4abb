"""Frames finished on the rendering device: the camera model and the ego-lane labels as kernels.

Why: on a GPU the CPU's share of a frame (``pipeline.finish_frame``: numpy noise, motion blur,
auto-exposure, the ego lane's k-d tree, ~175 ms) bounds a render at ~70 frames/s. A renderer
that offers ``render_finished`` (the warp renderer: ``plugins/roadtwin_warp_render/post.py``)
runs the same camera model and labels next to its G-buffer, on batches of frames, and hands back
8-bit images and labels; the frame sink's workers only JPEG-encode, grow thin classes and write.
Used on CUDA devices only by default (``RenderContext.device_finish``: True forces it, e.g. on the
CPU in tests), so ``--device cpu`` keeps its bytes; on CUDA the bytes are the device model's (other
random numbers than numpy's), and frame ``i`` still depends only on ``(seed, i)``.
"""
from __future__ import annotations

import time
from typing import Iterator

import numpy as np

from ...render import Frame, StereoCamera
from ...render.randomize import decode_jpeg, encode_jpeg
from .pipeline import DEFECT_CLASSES, FrameJob, FrameOut, RenderContext

__all__ = ["finish_on_device", "device_requests", "encode_device_frame", "render_on_device"]

BATCH = 16


def finish_on_device(ctx: RenderContext, jobs: list[FrameJob], device: str | None) -> bool:
    """Whether these frames are finished on the device: a renderer that can, mono cameras, no
    normals asked for, and a CUDA device (or ``ctx.device_finish`` True)."""
    if not hasattr(ctx.renderer, "render_finished") or ctx.normals or ctx.device_finish is False:
        return False
    if any(isinstance(j.camera, StereoCamera) for j in jobs):
        return False
    return bool(ctx.device_finish) or str(device or "").startswith("cuda")


def device_requests(ctx: RenderContext, jobs: list[FrameJob]) -> Iterator[dict]:
    """One request a frame (see ``WarpRenderer.render_finished``): camera, parameters, look,
    camera model, and the class map's tables with the ego lane (the camera's arc length along
    it from ``ego_lane.lane_coordinates``, as the CPU path takes it)."""
    # scipy: Ray render workers import apps.render with numpy, warp, shapely, Pillow and pluggy only
    from ...render.ego_lane import lane_coordinates

    names = list(ctx.mesh.classes)
    tables = ctx.class_map.lookup_tables(names) if ctx.class_map is not None else None
    for job in jobs:
        labels: dict = {"label_distance": job.params.label_distance_m}
        if tables is not None:
            labels["plain"], labels["inside"] = np.asarray(tables[0], np.uint8), np.asarray(tables[1], np.uint8)
            if job.lane_xy is not None and ctx.class_map.ego:
                lane = np.asarray(job.lane_xy, np.float64).reshape(-1, 2)
                s_cam, _, _ = lane_coordinates(job.camera.position[None, :2], lane)
                labels.update(lane=lane, half_width=ctx.lane_width_m / 2, s_cam=float(s_cam[0]))
        yield {"camera": job.camera, "params": job.params, "look": job.look, "effects": job.effects,
               "labels": labels}


def render_on_device(ctx: RenderContext, scene, jobs: list[FrameJob]) -> Iterator[tuple[FrameJob, FrameOut]]:
    """Each job's frame, finished on the device, as a FrameOut still to be encoded
    (:func:`encode_device_frame`); ``timings['render']``: the batch's seconds shared out."""
    done = ctx.renderer.render_finished(scene, device_requests(ctx, jobs), jobs[0].params if jobs else None,
                                        batch=BATCH)
    t0 = time.perf_counter()
    for job, out in zip(jobs, done):
        t1 = time.perf_counter()
        frame = Frame(index=job.index, camera=job.camera, depth=out["depth"], semantic=out["labels"],
                      instance=out["instance"])
        yield job, FrameOut(frame, out["rgb8"], None, backend=getattr(scene, "backend", None),
                            device=getattr(scene, "device", None), timings={"render": t1 - t0})
        t0 = time.perf_counter()


def encode_device_frame(ctx: RenderContext, job: FrameJob, out: FrameOut) -> FrameOut:
    """The host's share of a device-finished frame: JPEG bytes (the camera's, as the CPU model
    writes them, and the image decoded from them), thin classes grown, defect pixel shares."""
    t0 = time.perf_counter()
    if job.effects is not None:
        out.image_bytes = encode_jpeg(out.rgb8, job.effects.jpeg_quality)
        out.rgb8 = decode_jpeg(out.image_bytes)
    t1 = time.perf_counter()
    names = list(ctx.mesh.classes)
    if ctx.class_map is not None:
        out.frame.semantic = ctx.class_map.within_range(ctx.class_map.spread(out.frame.semantic), out.frame.depth)
        names = list(ctx.class_map.classes)
    labels = out.frame.semantic
    out.defect_share = {c: float((labels == names.index(c)).mean()) for c in DEFECT_CLASSES if c in names}
    out.timings.update(sensor=t1 - t0, labels=time.perf_counter() - t1)
    return out
