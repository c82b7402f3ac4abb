"""Objects and signals of a road -> world-frame :class:`~roadtwin_core.MapObject`s.

Where (the standard's reference-line frame, the same evaluation the lanes use): (x, y) =
reference line at s + t times its left normal scaled by cos(superelevation) (t is measured from
the reference line, not from the laneOffset-shifted centre lane); z = elevation(s) +
t * sin(superelevation) + zOffset. Heading: an object's ``hdg`` is relative to the road's heading
at s; a signal's face looks against the traffic it is for (orientation "+": towards -s, "-" and
"none": towards +s) turned by its ``hOffset``. Pitch and roll are kept as the file gives them.
Size (length, width, height): a radius without length/width gives a 2r x 2r box.

``<repeat>``: an object with repeats is replaced by their copies (the standard: the repeat's
attributes overrule the object's). distance > 0: a copy every ``distance`` m from s to
s + length; distance 0 (a continuous object: a guardrail, a fence) becomes pieces of at most
:data:`CONTINUOUS_PIECE_M` from chord to chord, each as long as its chord and turned along it.
t, zOffset and the sizes go linearly from their Start to their End value (the object's where
the file gives none). A repeat running past the road's end is cut there. Ids:
``<object id>_<repeat>_<copy>``.
"""
from __future__ import annotations

import math

import numpy as np

from roadtwin_core import MapObject

from ._objects_xml import ObjectRecord, Repeat
from ._refline import ReferenceLine, eval_cubics
from ._xodr import Road

CONTINUOUS_PIECE_M = 4.0     # a guardrail section (roadtwin's guardrail prototype is 4 m long)


def _frame(road: Road, ref: ReferenceLine, s: np.ndarray, t: np.ndarray, z_offset: np.ndarray):
    """World x, y, z and road heading at (s, t)."""
    s = np.clip(np.asarray(s, np.float64), 0.0, road.length)
    x, y, h = ref(s)
    sf = eval_cubics(road.superelevation, s)
    c = np.cos(sf)
    x, y = x - t * np.sin(h) * c, y + t * np.cos(h) * c
    z = eval_cubics(road.elevation, s) + t * np.sin(sf) + z_offset
    return x, y, z, h


def _wrap(a: float) -> float:
    return float(math.remainder(a, 2.0 * math.pi))


def _size(length: float, width: float, height: float, radius: float) -> tuple[float, float, float]:
    if radius > 0:
        length, width = length or 2.0 * radius, width or 2.0 * radius
    return float(length), float(width), float(height)


def _object(rec: ObjectRecord, oid: str, xyz, heading: float, size) -> MapObject:
    return MapObject(oid, rec.kind, rec.type, tuple(float(v) for v in xyz), (_wrap(heading), rec.pitch, rec.roll),
                     size, rec.subtype, rec.name, "", rec.dynamic)


def _single(road: Road, ref: ReferenceLine, rec: ObjectRecord) -> MapObject:
    x, y, z, h = _frame(road, ref, np.array([rec.s]), np.array([rec.t]), np.array([rec.z_offset]))
    heading = h[0] + rec.h_offset
    if rec.kind == "signal" and rec.orientation == "+":
        heading += math.pi
    sz = rec.sizes
    return _object(rec, rec.id, (x[0], y[0], z[0]), heading, _size(sz["length"], sz["width"], sz["height"],
                                                                   sz["radius"]))


def _lerp(pair, default: float, u: np.ndarray) -> np.ndarray:
    a = default if pair[0] is None else pair[0]
    b = a if pair[1] is None else pair[1]
    return a + (b - a) * u


def _copies(road: Road, ref: ReferenceLine, rec: ObjectRecord, rep: Repeat, k: int) -> list[MapObject]:
    a = max(rep.s, 0.0)
    b = min(rep.s + rep.length, road.length)
    span = max(b - a, 0.0)

    def values(u):
        sizes = {key: _lerp(rep.sizes.get(key, (None, None)), rec.sizes[key], u) for key in rec.sizes}
        return _lerp(rep.t, rec.t, u), _lerp(rep.z_offset, rec.z_offset, u), sizes

    if rep.distance > 0 or span < 1e-9:
        n = int(math.floor(span / rep.distance + 1e-9)) + 1 if rep.distance > 0 else 1
        s = a + rep.distance * np.arange(n)
        u = (s - a) / span if span > 0 else np.zeros(n)
        t, zo, sz = values(u)
        x, y, z, h = _frame(road, ref, s, t, zo)
        return [_object(rec, f"{rec.id}_{k}_{j}", (x[j], y[j], z[j]), h[j] + rec.h_offset,
                        _size(*(sz[key][j] for key in ("length", "width", "height", "radius"))))
                for j in range(n)]
    n = max(1, math.ceil(span / CONTINUOUS_PIECE_M - 1e-9))
    u = np.arange(n + 1) / n
    t, zo, sz = values(u)
    x, y, z, _ = _frame(road, ref, a + span * u, t, zo)
    out = []
    for j in range(n):
        dx, dy = x[j + 1] - x[j], y[j + 1] - y[j]
        mid = (0.5 * (x[j] + x[j + 1]), 0.5 * (y[j] + y[j + 1]), 0.5 * (z[j] + z[j + 1]))
        width, height = (0.5 * (sz[key][j] + sz[key][j + 1]) for key in ("width", "height"))
        out.append(_object(rec, f"{rec.id}_{k}_{j}", mid, math.atan2(dy, dx) + rec.h_offset,
                           (math.hypot(dx, dy), float(width), float(height))))
    return out


def road_objects(road: Road, ref: ReferenceLine) -> list[MapObject]:
    """A road's objects and signals in the world frame (see the module docstring)."""
    out: list[MapObject] = []
    for rec in road.objects:
        if rec.repeats:
            for k, rep in enumerate(rec.repeats):
                out += _copies(road, ref, rec, rep, k)
        else:
            out.append(_single(road, ref, rec))
    for obj in out:
        obj.road = road.id
    return out
