"""The composer's preview as jobs for its helper process (:class:`~roadtwin_core.apps.compose.sidecar.Sidecar`).

Why: the preview (``import warp``, kernel loading, texture decoding, one frame, the map) costs
more than writing and validating the stage, and needs nothing of them but the looks layer. In
the helper it runs on the second core while the composer writes the heavy layers and validates.
:func:`warm_up_renderer` runs first, while the composer reads and places (one core idle): it
imports the renderer and renders one tiny frame, so its kernels are loaded, or compiled into
warp's kernel cache on a machine's first run, before the town arrives.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ...errors import RoadtwinError
from ...plugins import PluginManager
from ...render import Camera, Intrinsics, RenderParams, look_from
from ...render.scene import RenderMaterial, RenderMesh
from . import preview, preview_scene  # noqa: F401 - preview_scene: the town that render_preview receives

__all__ = ["warm_up_renderer", "render_preview"]

PREVIEW_RENDERER = "warp"


_PLUGINS = None


def _plugins(only=None):
    """This helper's plugin manager: only the renderer's plugin when the composer named it (the
    others' imports cost ~0.7 s of CPU and ~120 MB here), else all."""
    global _PLUGINS
    if _PLUGINS is None:
        _PLUGINS = PluginManager(only=only)
    return _PLUGINS


def _import_preview_modules() -> None:
    """What the preview loads on first use beyond this module's imports (OpenCV, an optional
    package, and Pillow's fonts), loaded while the helper waits for the town rather than after
    it arrives. The preview's own modules (USD, Pillow, ~0.25 s in all) come with this module,
    which the helper imports to run its first job, :func:`warm_up_renderer`."""
    import cv2  # noqa: F401

    preview._font(14), preview._font(12)


def warm_up_renderer(plugins: tuple[str, ...] | None = None) -> float:
    """Seconds spent loading the preview renderer (from the entry points ``plugins``; None: all)
    and rendering a 16 x 12 frame of a textured square. Without a usable renderer this does
    nothing: the preview then says why."""
    t0 = time.perf_counter()
    _import_preview_modules()
    try:
        renderer = _plugins(plugins).get("renderers", PREVIEW_RENDERER)
    except RoadtwinError:
        return 0.0
    rng = np.random.default_rng(0)
    texture = RenderMaterial("warm_up", rng.random((4, 4, 3), dtype=np.float32), np.full((4, 4, 1), 0.5, np.float32),
                             np.tile(np.array([0.5, 0.5, 1.0], np.float32), (4, 4, 1)))
    square = RenderMesh(np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float),
                        np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2), np.array([0, 1]), np.ones(2),
                        np.zeros((2, 3, 2)), ["driving", "pothole"], [texture, texture],
                        [{"id": 1, "defect_id": "warm_up", "type": "pothole", "class_id": 1, "attributes": {}}],
                        ["pothole"], "warm-up")
    camera = Camera(Intrinsics.from_fov(16, 12, 75.0), look_from((0.0, 0.0, 2.0), 0.0, -0.5))
    try:
        next(iter(renderer.render(square, [camera], RenderParams(backend=PREVIEW_RENDERER))))
    except ImportError:                              # plugin loaded, engine (warp) missing
        return 0.0
    return time.perf_counter() - t0


def render_preview(path: Path, town_stage: Path, title: str, town) -> dict:
    """``write_preview`` of the composer's in-memory town (``PreviewTown``); returns its seconds."""
    t0 = time.perf_counter()
    preview.write_preview(path, town_stage, pm=_plugins(), title=title, town=town)
    return {"preview_s": time.perf_counter() - t0}
