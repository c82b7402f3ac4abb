"""What renderers take (``RenderParams``) and give back (``Frame``): the renderer contract's
data, numpy only. A renderer plugin registers an object with ``name``, ``description``,
``Params = RenderParams`` and ``render(scene, cameras, params) -> iterator of Frame``, where
``scene`` is a :class:`RenderMesh` (or a town scene to build one from) and ``cameras`` a list
of :class:`Camera` / :class:`StereoCamera`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..params import field
from .cameras import Camera

WEATHERS = ("clear", "fog", "wet", "dusk")


@dataclass
class RenderParams:
    weather: str = field("clear", doc="clear | fog | wet | dusk (lighting and weather preset)")
    sun_elevation_deg: Optional[float] = field(None, lo=-10.0, hi=90.0, doc="override the preset's sun elevation")
    sun_azimuth_deg: Optional[float] = field(None, lo=-360.0, hi=360.0, doc="sun azimuth, 0 = +X, counter-clockwise")
    fog_density: Optional[float] = field(None, lo=0.0, hi=10.0, doc="override: exponential fog, 1/m")
    wetness: Optional[float] = field(None, lo=0.0, hi=1.0, doc="override: 0 dry .. 1 soaked road")
    shadows: bool = field(True, doc="ray-traced sun shadows")
    shade: bool = field(True, doc="compute RGB (off: G-buffer only)")
    seed: int = field(0, lo=0, doc="seed (kept for reproducible settings; textures come from the stage)")
    device: Optional[str] = field(None, doc="compute device, e.g. cpu or cuda:0 (default: the renderer's)")
    backend: str = field("auto", doc="ray caster: auto | warp | open3d (CPU only)")
    max_distance_m: float = field(1000.0, lo=1.0, doc="rays end here (background beyond)")
    label_distance_m: float = field(150.0, lo=1.0, doc="semantic labels beyond this distance are 255 (ignore)")
    min_clearance_m: float = field(0.05, lo=0.0, doc="a camera nearer than this to any surface is an error")


@dataclass
class Frame:
    """One rendered view. Arrays are (H, W[, 3]); ``rgb`` is linear radiance (float32, roughly
    0..1, tone-mapped by the writers), ``depth`` z-depth in metres (0 = no hit), ``normal`` unit
    normals in camera coordinates (OpenCV axes; zero where no hit), ``semantic`` uint8 class ids,
    ``instance`` int32 (0 = none), ``disparity`` left-view f*B/Z in pixels (0 = no hit) and
    ``occluded`` True where the left pixel's point is not visible from the right camera."""

    index: int
    camera: Camera
    time_s: float | None = None
    rgb: np.ndarray | None = None
    depth: np.ndarray | None = None
    normal: np.ndarray | None = None
    semantic: np.ndarray | None = None
    instance: np.ndarray | None = None
    face: np.ndarray | None = None
    right_camera: Camera | None = None
    rgb_right: np.ndarray | None = None
    disparity: np.ndarray | None = None
    occluded: np.ndarray | None = None
