"""Typed, validated parameters for registered things (defect types, mergers, ...).

Parameters are plain dataclasses. ``check_params`` validates every float field (finite,
and positive where the field's metadata says so) so a plugin author only declares bounds.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

from .errors import RoadtwinError


def field(default: Any, *, lo: float | None = None, hi: float | None = None, doc: str = ""):
    """A dataclass field with inclusive bounds ``lo``/``hi`` checked by :func:`check_params`."""
    return dataclasses.field(default=default, metadata={"lo": lo, "hi": hi, "doc": doc})


def check_params(params: Any, owner: str) -> Any:
    """Raise RoadtwinError naming ``owner.field`` for NaN/inf or out-of-bounds values."""
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            continue
        if not math.isfinite(float(value)):
            raise RoadtwinError(f"{owner}: parameter {f.name} must be finite, got {value}")
        lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
        if lo is not None and value < lo:
            raise RoadtwinError(f"{owner}: parameter {f.name} must be >= {lo}, got {value}")
        if hi is not None and value > hi:
            raise RoadtwinError(f"{owner}: parameter {f.name} must be <= {hi}, got {value}")
    return params


def make_params(cls: type, values: dict[str, Any], owner: str) -> Any:
    """Build and check a params dataclass from a dict, naming unknown keys clearly."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise RoadtwinError(f"{owner}: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
    return check_params(cls(**values), owner)


def describe_params(cls: type | None) -> list[dict[str, Any]]:
    """Field name, type, default and bounds, for `roadtwin plugins` and docs."""
    if cls is None:
        return []
    out = []
    for f in dataclasses.fields(cls):
        out.append({"name": f.name, "type": getattr(f.type, "__name__", str(f.type)),
                    "default": f.default, "lo": f.metadata.get("lo"), "hi": f.metadata.get("hi"),
                    "doc": f.metadata.get("doc", "")})
    return out
