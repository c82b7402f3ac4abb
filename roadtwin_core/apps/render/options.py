"""``roadtwin render``'s options (:class:`RenderOptions`) and their checks: image sizes, numeric
ranges, ``--views``, rig defaults."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from ...errors import RoadtwinError
from ...render.frames import RenderParams
from ...render.rig_usd import rig_preset
from ...render.view_sampler import DEFECT_DISTANCE_M

__all__ = ["DEFECT_DISTANCE_M", "MAX_FRAMES", "RenderOptions", "Rig", "ViewSpec", "check_range", "check_rig", "parse_size",
           "parse_views", "pick", "resolve_rig"]

MAX_DEFECT_DISTANCE_M = RenderParams().max_distance_m      # nothing farther is drawn


@dataclass
class RenderOptions:
    """What to render, one field per ``roadtwin render`` option and with its default; ``None``
    means "the rig's, else the built-in default" (see :func:`resolve_rig`). Checked by
    :func:`~roadtwin_core.apps.render.run.run_render` before anything is read or written."""

    frames: int = 8
    rig: str | None = None                 # survey | dashcam | stereo | inspection
    views: str | None = None               # random | defects:SHARE[:clear][:NEAR-FAR]; default: stage cameras, else random
    randomize: bool = False                # per-frame domain randomization
    classmap: str | None = None            # class map TOML file or builtin:NAME
    size: str | None = None                # WIDTHxHEIGHT
    stereo: bool = False
    baseline: float | None = None          # stereo baseline, m
    events: bool = False                   # also simulate an event camera on a continuous drive
    formats: str | None = None             # comma-separated dataset formats (default: all that apply)
    seed: int = 0
    hfov: float | None = None              # degrees
    height: float | None = None            # camera height above the road, m
    pitch: float | None = None             # degrees, negative looks down
    poses: str | Path | None = None        # JSON poses file instead of lane sampling
    weather: str = "clear"
    material: str | None = None            # roadMaterial variant
    renderer: str = "warp"                 # renderer plugin
    device: str | None = None              # cpu | cuda | cuda:N (default: the renderer's)
    backend: str = "auto"                  # ray caster: auto | warp | open3d
    executor: str = "local"                # local | serial | ray
    workers: int | None = None
    ray_address: str | None = None
    speed: float = 8.0                     # event drive speed, m/s
    event_rate: float = 500.0              # event drive frame rate, Hz
    event_frames: int = 50
    event_size: str | None = None          # default: size
    event_threshold: float = 0.2
    renderer_params: dict[str, Any] = field(default_factory=dict)   # --param: values for the renderer's Params


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


class ViewSpec(NamedTuple):
    """What ``--views`` asks for: kind (none | random | defects), the share of frames aimed at a
    defect, what the other frames avoid (uniform | clear) and how far ahead an aimed defect lies."""

    kind: str
    share: float | None = None
    background: str = "uniform"
    distance_m: tuple[float, float] = DEFECT_DISTANCE_M


def parse_views(text: str | None) -> ViewSpec:
    """``random`` | ``defects:SHARE[:clear][:NEAR-FAR]`` -> :class:`ViewSpec`. ``NEAR-FAR`` (metres
    ahead of the camera, default 5-25) lets a survey's measured defect distances be matched (the
    road_defects_br train potholes lie 2.8-11.1 m ahead, 10th-90th percentile: bench/defect_priors.py)."""
    if text is None:
        return ViewSpec("none")
    t = str(text).strip().lower()
    if t == "random":
        return ViewSpec("random")
    m = re.fullmatch(r"defects:([0-9]*\.?[0-9]+)(?::(clear|uniform))?(?::([0-9]*\.?[0-9]+)-([0-9]*\.?[0-9]+))?", t)
    if m:
        share = float(m.group(1))
        near, far = (float(m.group(3)), float(m.group(4))) if m.group(3) else DEFECT_DISTANCE_M
        if 0.0 <= share <= 1.0 and 0.0 <= near < far <= MAX_DEFECT_DISTANCE_M:
            return ViewSpec("defects", share, m.group(2) or "uniform", (near, far))
    raise RoadtwinError(f"--views must be random or defects:SHARE[:clear][:NEAR-FAR] with SHARE in 0..1 and "
                        f"0 <= NEAR < FAR <= {MAX_DEFECT_DISTANCE_M:g} metres (e.g. defects:0.6 or defects:0.8:clear:2.5-12), "
                        f"got {text!r}")


def pick(explicit, preset_value, default):
    """The explicit option, else the rig preset's value, else the default."""
    return explicit if explicit is not None else preset_value if preset_value is not None else default


@dataclass(frozen=True)
class Rig:
    """The camera rig a render uses: a preset's values (``--rig``) with explicit options over them."""

    width: int
    height_px: int
    hfov_deg: float
    mount_height_m: float
    pitch_deg: float | None
    stereo: bool
    baseline_m: float
    preset: object | None          # the ``RigPreset`` named by --rig, if any
    size_given: bool               # --size was given (stage cameras are then rendered at that size)


def resolve_rig(rig: str | None, size: str | None, hfov: float | None, height: float | None, pitch: float | None,
                baseline: float | None, stereo: bool) -> Rig:
    """``--rig`` and the options that override it, checked (one line naming the option)."""
    preset = rig_preset(rig) if rig is not None else None
    size_text = size if size is not None else (f"{preset.width}x{preset.height}" if preset else "640x480")
    width, height_px = parse_size(size_text)
    return Rig(width, height_px, pick(hfov, preset and preset.hfov_deg, 90.0), pick(height, preset and preset.height_m, 1.5),
               pick(pitch, preset and preset.pitch_deg, None), bool(stereo or (preset is not None and preset.baseline_m)),
               pick(baseline, preset and preset.baseline_m, 0.54), preset, size is not None)


def check_rig(r: Rig) -> None:
    check_range("--hfov", r.hfov_deg, 1.0, 179.0, "degrees")
    check_range("--height", r.mount_height_m, 1e-3, 1000.0, "m")
    if r.pitch_deg is not None:
        check_range("--pitch", r.pitch_deg, -89.0, 89.0, "degrees")
    if r.stereo:
        check_range("--baseline", r.baseline_m, 1e-3, 100.0, "m")
