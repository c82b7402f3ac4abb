"""Rendering frames in chunks on any executor: what one worker does with its share of frames.

Why chunks and a per-process cache: preparing a scene (uploading a town to a ray caster, packing
its textures) costs seconds, a 512x320 frame a fraction of that. A worker keeps the prepared
scene of the render it serves (keyed by a token of that render) and renders every chunk it gets
with it. Every input of frame ``i`` is fixed before the work is handed out (its camera, render
parameters, material look, sensor effects and ego lane are functions of ``(seed, i)`` and the
stage), so the output does not depend on the executor, the chunking or the worker order.

A frame is two parts: :func:`render_views` (the renderer: where the device is) and
:func:`finish_frame` (the CPU's share: the camera model, the labels), which ``frame_sink`` may
run on other threads or processes than the first. Finished frames are compact, already-final
products: the 8-bit image (and its JPEG bytes when the sensor model ran), the labels as written
(class-mapped, with the ego lane, cracks grown), the instance map, depth, optional normals and
stereo, with each part's seconds (``timings``); the dataset writer only writes them.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import RoadtwinError
from ...render import Camera, Frame, RenderParams, StereoCamera, to_srgb8
from ...render.randomize import apply_sensor

__all__ = ["FrameJob", "FrameOut", "RenderContext", "finish_frame", "forget", "prepared_scene", "render_chunk",
           "render_job", "render_views"]

_PREPARED: dict[str, Any] = {}
DEFECT_CLASSES = ("pothole", "crack")


@dataclass
class FrameJob:
    """Everything frame ``index`` needs, decided before rendering."""

    index: int
    camera: Camera | StereoCamera
    params: RenderParams
    look: Any = None                       # scene_look.MaterialLook or None
    effects: Any = None                    # randomize.ImageEffects or None (plain tone mapping)
    lane_xy: np.ndarray | None = None      # ego lane centreline ahead (class maps with an ego rule)
    record: dict = field(default_factory=dict)


@dataclass
class RenderContext:
    """What every worker shares (shipped once per worker)."""

    token: str
    renderer: Any
    mesh: Any                              # RenderMesh
    params: RenderParams
    class_map: Any = None                  # classmap.ClassMap or None
    lane_width_m: float = 3.5
    normals: bool = False
    device_finish: bool | None = None      # camera model and labels on the device: None = on CUDA (device_frames)


@dataclass
class FrameOut:
    frame: Frame                           # rgb dropped; semantic = the labels as written
    rgb8: np.ndarray
    image_bytes: bytes | None = None
    rgb8_right: np.ndarray | None = None
    image_bytes_right: bytes | None = None
    defect_share: dict = field(default_factory=dict)   # class -> share of the frame's pixels
    backend: str | None = None
    device: str | None = None
    timings: dict = field(default_factory=dict)        # phase -> seconds (prepare, render, sensor, labels)
    encoded: Any = None                    # writers' EncodedFrame: the files already as bytes (gpu_shards)


def _prepared(ctx: RenderContext):
    scene = _PREPARED.get(ctx.token)
    if scene is None:
        _PREPARED.clear()                  # one render at a time per process: drop the last one
        scene = ctx.renderer.prepare(ctx.mesh, ctx.params)
        _PREPARED[ctx.token] = scene
    return scene


def prepared_scene(ctx: RenderContext) -> tuple[Any, float]:
    """This process's prepared scene of ``ctx`` and the seconds preparing it took now (0 when cached)."""
    t0 = time.perf_counter()
    cached = ctx.token in _PREPARED
    scene = _prepared(ctx)
    return scene, 0.0 if cached else time.perf_counter() - t0


def forget(token: str) -> None:
    """Drop a render's prepared scene from this process (the serial executor's cache)."""
    _PREPARED.pop(token, None)


def render_chunk(ctx: RenderContext, jobs: list[FrameJob]) -> list[FrameOut]:
    """Render ``jobs`` in order (module-level, so process pools and Ray can ship it)."""
    scene, t_prepare = prepared_scene(ctx)
    outs = [render_job(ctx, scene, job) for job in jobs]
    if outs and t_prepare:
        outs[0].timings["prepare"] = t_prepare
    return outs


def render_job(ctx: RenderContext, scene, job: FrameJob) -> FrameOut:
    """One frame, start to finish: :func:`render_views` then :func:`finish_frame`."""
    return finish_frame(ctx, scene, job, render_views(ctx, scene, job))


def render_views(ctx: RenderContext, scene, job: FrameJob) -> tuple[Frame, float]:
    """The renderer's part of a frame (ray casting and shading, arrays on the host) and its seconds."""
    t0 = time.perf_counter()
    kwargs = {"look": job.look} if job.look is not None else {}
    try:
        frame = next(iter(ctx.renderer.render(scene, [job.camera], job.params, **kwargs)))
    except RoadtwinError as exc:
        raise RoadtwinError(f"frame {job.index}: {exc}") from None
    frame.index = job.index
    return frame, time.perf_counter() - t0


def finish_frame(ctx: RenderContext, scene, job: FrameJob, rendered: tuple[Frame, float]) -> FrameOut:
    """The CPU part of a frame: the camera model (or plain tone mapping) and the labels as
    written. Touches only this frame's arrays, so frames may be finished on several threads."""
    frame, t_render = rendered
    t0 = time.perf_counter()
    left = job.camera.left if isinstance(job.camera, StereoCamera) else job.camera
    rgb8, data = _image(frame.rgb, job.effects, left, frame.depth)
    rgb8_r = data_r = None
    if frame.rgb_right is not None:
        rgb8_r, data_r = _image(frame.rgb_right, job.effects, job.camera.right, frame.depth)
    t1 = time.perf_counter()
    labels, names = _labels(ctx, job, frame, left)
    share = {c: float((labels == names.index(c)).mean()) for c in DEFECT_CLASSES if c in names}
    frame.semantic = labels
    frame.rgb = frame.rgb_right = None
    frame.face = None
    if not ctx.normals:
        frame.normal = None
    timings = {"render": t_render, "sensor": t1 - t0, "labels": time.perf_counter() - t1}
    return FrameOut(frame, rgb8, data, rgb8_r, data_r, share, getattr(scene, "backend", None),
                    getattr(scene, "device", None), timings)


def _image(rgb: np.ndarray, effects, camera: Camera, depth: np.ndarray) -> tuple[np.ndarray, bytes | None]:
    """What the camera records: the sensor model's (8-bit, JPEG bytes), else tone-mapped and no bytes."""
    if effects is not None:
        return apply_sensor(rgb, effects, camera, depth)
    return to_srgb8(rgb), None


def _labels(ctx: RenderContext, job: FrameJob, frame: Frame, left: Camera) -> tuple[np.ndarray, list[str]]:
    """The labels as written (class-mapped with the ego lane, thin classes grown) and their names."""
    names = list(ctx.mesh.classes)
    if ctx.class_map is None:
        return frame.semantic, names
    ego = None
    if job.lane_xy is not None and ctx.class_map.ego:
        # scipy: Ray render workers import apps.render with numpy, warp, shapely, Pillow and pluggy only
        from ...render.ego_lane import ego_lane_mask

        surface = (frame.depth > 0) & (frame.semantic != 0) & (frame.semantic != 255)
        ego = ego_lane_mask(left, frame.depth, job.lane_xy, ctx.lane_width_m, surface=surface)
    labels = ctx.class_map.within_range(ctx.class_map.spread(ctx.class_map.apply(frame.semantic, names, ego)), frame.depth)
    return labels, list(ctx.class_map.classes)
