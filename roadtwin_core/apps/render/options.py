"""Checks of ``roadtwin render``'s options: image sizes, numeric ranges, ``--views``, rig defaults."""
from __future__ import annotations

import math
import re

from ...errors import RoadtwinError

__all__ = ["MAX_FRAMES", "check_range", "parse_size", "parse_views", "pick"]


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


def pick(explicit, preset_value, default):
    """The explicit option, else the rig preset's value, else the default."""
    return explicit if explicit is not None else preset_value if preset_value is not None else default

