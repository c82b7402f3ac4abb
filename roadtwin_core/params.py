"""Typed, validated parameters for registered things (defect types, mergers, ...).

Parameters are plain dataclasses. ``check_params`` validates every float field (finite,
and positive where the field's metadata says so) so a plugin author only declares bounds.
``--param key=value`` on the command line goes through :func:`parse_param_options` and
:func:`apply_params`, i.e. the same :func:`make_params` / :func:`check_params` a layout file's
values go through.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
import tomllib
from typing import Any, Sequence

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


PARAM_HELP = ("plugin parameter KEY=VALUE (a TOML value: 0.5, 3, true, \"text\"); repeatable; "
              "`roadtwin plugins --params NAME` lists them")


def parse_param_options(items: Sequence[str] | None) -> dict[str, Any]:
    """``["depth_m=0.1", "name=cdt"]`` -> ``{"depth_m": 0.1, "name": "cdt"}``.

    Values are TOML scalars (numbers, booleans, quoted strings, arrays); a bare word that is not
    TOML (``weather=rain``) is taken as a string, which :func:`apply_params` then checks against
    the field's type."""
    out: dict[str, Any] = {}
    for item in items or ():
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key.isidentifier():
            raise RoadtwinError(f"--param {item!r}: expected KEY=VALUE (e.g. --param depth_m=0.1)")
        if key in out:
            raise RoadtwinError(f"--param {key}: given twice")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        if isinstance(value, dict):
            raise RoadtwinError(f"--param {key}: expected a number, boolean, string or array, got {text!r}")
        out[key] = value
    return out


def _typed(f: dataclasses.Field, value: Any, owner: str) -> Any:
    """``value`` as the type of the field's default (int -> float where a float is wanted)."""
    default = f.default if f.default is not dataclasses.MISSING else None
    want = None if default is None else type(default)
    if want is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if want is tuple and isinstance(value, list):
        return tuple(value)
    if want is not None and not isinstance(value, want) or (want is int and isinstance(value, bool)):
        raise RoadtwinError(f"{owner}: parameter {f.name} must be {want.__name__}, got {value!r}")
    return value


def apply_params(base: Any, values: dict[str, Any], owner: str) -> Any:
    """``base`` (a params dataclass, or an instance to start from) with ``values`` set, type- and
    bounds-checked. Unknown keys and bad values raise one line naming ``owner`` and the field."""
    cls = base if isinstance(base, type) else type(base)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise RoadtwinError(f"{owner}: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(fields)) or 'none'}")
    typed = {k: _typed(fields[k], v, owner) for k, v in values.items()}
    params = cls(**typed) if isinstance(base, type) else dataclasses.replace(base, **typed)
    return check_params(params, owner)


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
