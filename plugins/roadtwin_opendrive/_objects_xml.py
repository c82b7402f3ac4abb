"""A road's ``<objects>`` and ``<signals>`` -> plain records (xml.etree; no geometry here).

Read (ASAM OpenDRIVE 1.4-1.8): ``<object>`` s, t, zOffset, hdg, pitch, roll, type, subtype,
name, id, length, width, radius, height, orientation and its ``<repeat>`` elements (s, length,
distance, tStart/tEnd, zOffset/height/width/length/radius Start/End); ``<signal>`` s, t, zOffset,
hOffset, pitch, roll, orientation, dynamic, country, type, subtype, name, id, height, width.
Not read: ``<outline(s)>``, ``<material>``, ``<validity>``, ``<objectReference>``,
``<signalReference>``, ``<bridge>``/``<tunnel>``. A number that is not one, a negative size, or an
s outside the road is one error line naming the file, the road and the object.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

# s may overshoot the road's ends by this much (rounding in map tools) before it is an error
S_TOL_M = 0.01
_SIZE_KEYS = ("length", "width", "height", "radius")


@dataclass
class Repeat:
    """``<repeat>``: copies every ``distance`` m over [s, s + length]; distance 0 = continuous.
    Start/end values are None where the file leaves them to the object."""

    s: float
    length: float
    distance: float
    t: tuple[float | None, float | None] = (None, None)
    z_offset: tuple[float | None, float | None] = (None, None)
    sizes: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)


@dataclass
class ObjectRecord:
    """An ``<object>`` (kind "object") or ``<signal>`` (kind "signal") as the file writes it.
    ``h_offset`` is the object's hdg or the signal's hOffset (relative to the road's heading)."""

    kind: str
    id: str
    type: str
    subtype: str
    name: str
    s: float
    t: float
    z_offset: float
    h_offset: float
    pitch: float
    roll: float
    orientation: str
    sizes: dict[str, float]          # length, width, height, radius (0: not given)
    repeats: list[Repeat] = field(default_factory=list)
    dynamic: bool = False


def _local(tag: object) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _children(el: ET.Element | None, tag: str) -> list[ET.Element]:
    return [] if el is None else [c for c in el if _local(c.tag) == tag]


def _text(el: ET.Element, key: str, default: str = "") -> str:
    return " ".join((el.get(key) or default).split())


def read_road_objects(rd, road_el: ET.Element, where: str, length: float) -> list[ObjectRecord]:
    """Every object and signal of one road, in file order. ``rd``: the file reader (num, fail)."""
    out: list[ObjectRecord] = []
    for group, tag in (("objects", "object"), ("signals", "signal")):
        for parent in _children(road_el, group):
            for k, el in enumerate(_children(parent, tag)):
                rec = _record(rd, el, tag, k, where)
                _check_s(rd, rec.s, rec, where, length)
                if tag == "object":
                    rec.repeats = [_repeat(rd, r, rec, where, length) for r in _children(el, "repeat")]
                out.append(rec)
    return out


def _record(rd, el: ET.Element, tag: str, k: int, where: str) -> ObjectRecord:
    oid = _text(el, "id") or f"#{k + 1}"
    ow = f"{where}: {tag} {oid}"
    sizes = {key: rd.num(el, key, ow, 0.0) for key in _SIZE_KEYS if tag == "object" or key in ("width", "height")}
    sizes = {key: sizes.get(key, 0.0) for key in _SIZE_KEYS}
    bad = [key for key, v in sizes.items() if v < 0]
    if bad:
        raise rd.fail(ow, f"{bad[0]}={sizes[bad[0]]:g} is negative")
    return ObjectRecord(tag, oid, _text(el, "type"), _text(el, "subtype"), _text(el, "name"),
                        rd.num(el, "s", ow, limit=1e6), rd.num(el, "t", ow, 0.0, limit=1e4),
                        rd.num(el, "zOffset", ow, 0.0, limit=1e4),
                        rd.num(el, "hdg" if tag == "object" else "hOffset", ow, 0.0, limit=1e3),
                        rd.num(el, "pitch", ow, 0.0, limit=1e3), rd.num(el, "roll", ow, 0.0, limit=1e3),
                        _text(el, "orientation", "none"), sizes, dynamic=_text(el, "dynamic") == "yes")


def _check_s(rd, s: float, rec: ObjectRecord, where: str, length: float) -> None:
    if not -S_TOL_M <= s <= length + S_TOL_M:
        raise rd.fail(f"{where}: {rec.kind} {rec.id}", f"s={s:g} lies outside the road (0..{length:g} m)")


def _repeat(rd, el: ET.Element, rec: ObjectRecord, where: str, length: float) -> Repeat:
    rw = f"{where}: object {rec.id}: repeat"

    def pair(key: str) -> tuple[float | None, float | None]:
        return tuple(rd.num(el, f"{key}{end}", rw, limit=1e4) if el.get(f"{key}{end}") is not None else None
                     for end in ("Start", "End"))

    rep = Repeat(rd.num(el, "s", rw, limit=1e6), rd.num(el, "length", rw, limit=1e6),
                 rd.num(el, "distance", rw, 0.0, limit=1e6), pair("t"), pair("zOffset"),
                 {key: pair(key) for key in _SIZE_KEYS})
    _check_s(rd, rep.s, rec, where, length)
    if rep.length < 0 or rep.distance < 0:
        raise rd.fail(rw, f"length and distance must be >= 0, got length={rep.length:g} distance={rep.distance:g}")
    if any(v is not None and v < 0 for pr in rep.sizes.values() for v in pr):
        raise rd.fail(rw, "sizes (length, width, height, radius Start/End) must be >= 0")
    return rep
