"""Rendering frames in chunks on any executor: what one worker does with its share of frames.

Why chunks and a per-process cache: preparing a scene (uploading a town to a ray caster, packing
its textures) costs seconds, a 512x320 frame a fraction of that. A worker keeps the prepared
scene of the render it serves (keyed by a token of that render) and renders every chunk it gets
with it. Every input of frame ``i`` is fixed before the work is handed out (its camera, render
parameters, material look, sensor effects and ego lane are functions of ``(seed, i)`` and the
stage), so the output does not depend on the executor, the chunking or the worker order.

A worker returns compact, already-final products: the 8-bit image (and its JPEG bytes when the
sensor model ran), the labels as written (class-mapped, with the ego lane, cracks grown), the
instance map, depth, optional normals and stereo; the writer in the main process only writes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import RoadtwinError
from ...render import Camera, Frame, RenderParams, StereoCamera, to_srgb8
from ...render.randomize import apply_sensor

__all__ = ["FrameJob", "FrameOut", "RenderContext", "forget", "render_chunk", "render_job"]

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


def _prepared(ctx: RenderContext):
    scene = _PREPARED.get(ctx.token)
    if scene is None:
        _PREPARED.clear()                  # one render at a time per process: drop the last one
        scene = ctx.renderer.prepare(ctx.mesh, ctx.params)
        _PREPARED[ctx.token] = scene
    return scene


def forget(token: str) -> None:
    """Drop a render's prepared scene from this process (the serial executor's cache)."""
    _PREPARED.pop(token, None)


def render_chunk(ctx: RenderContext, jobs: list[FrameJob]) -> list[FrameOut]:
    """Render ``jobs`` in order (module-level, so process pools and Ray can ship it)."""
    scene = _prepared(ctx)
    return [render_job(ctx, scene, job) for job in jobs]


def render_job(ctx: RenderContext, scene, job: FrameJob) -> FrameOut:
    kwargs = {"look": job.look} if job.look is not None else {}
    try:
        frame = next(iter(ctx.renderer.render(scene, [job.camera], job.params, **kwargs)))
    except RoadtwinError as exc:
        raise RoadtwinError(f"frame {job.index}: {exc}") from None
    frame.index = job.index
    left = job.camera.left if isinstance(job.camera, StereoCamera) else job.camera
    if job.effects is not None:
        rgb8, data = apply_sensor(frame.rgb, job.effects, left, frame.depth)
    else:
        rgb8, data = to_srgb8(frame.rgb), None
    rgb8_r = data_r = None
    if frame.rgb_right is not None:
        if job.effects is not None:
            rgb8_r, data_r = apply_sensor(frame.rgb_right, job.effects, job.camera.right, frame.depth)
        else:
            rgb8_r = to_srgb8(frame.rgb_right)
    names = list(ctx.mesh.classes)
    if ctx.class_map is not None:
        ego = None
        if job.lane_xy is not None and ctx.class_map.ego:
            # scipy: Ray render workers import apps.render with numpy, warp, shapely, Pillow and pluggy only
            from ...render.ego_lane import ego_lane_mask

            surface = (frame.depth > 0) & (frame.semantic != 0) & (frame.semantic != 255)
            ego = ego_lane_mask(left, frame.depth, job.lane_xy, ctx.lane_width_m, surface=surface)
        labels = ctx.class_map.spread(ctx.class_map.apply(frame.semantic, names, ego))
        names = list(ctx.class_map.classes)
    else:
        labels = frame.semantic
    share = {c: float((labels == names.index(c)).mean()) for c in DEFECT_CLASSES if c in names}
    frame.semantic = labels
    frame.rgb = frame.rgb_right = None
    frame.face = None
    if not ctx.normals:
        frame.normal = None
    return FrameOut(frame, rgb8, data, rgb8_r, data_r, share, getattr(scene, "backend", None),
                    getattr(scene, "device", None))
