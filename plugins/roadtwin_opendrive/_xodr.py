"""OpenDRIVE XML -> plain records (xml.etree; no geometry here).

Only what the importer needs is read: header, roads (planView, elevationProfile,
lateralProfile/superelevation, lanes/laneOffset, laneSection left/center/right lanes with their
width and roadMark records, a roadMark's optional ``<type>`` line definitions), the road's objects
and signals (:mod:`roadtwin_opendrive._objects_xml`) and junction ids.
Every problem becomes one :class:`RoadtwinError` line naming the file and, where there is one,
the road id; nothing is skipped silently.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from roadtwin_core import RoadtwinError

from ._objects_xml import ObjectRecord, read_road_objects

# Sanity bounds (m): coordinates of projected maps reach ~1e7 m (UTM northings); a road longer
# than 1000 km or a lane wider than 100 m is a corrupt file, and such values overflow the
# geometry libraries downstream (shapely / triangle crash on 1e308).
MAX_ABS = 1e8
MAX_LENGTH_M = 1e6
MAX_WIDTH_M = 100.0
GAP_TOL_M = 0.01
GEOMETRY_KINDS = ("line", "arc", "spiral", "poly3", "paramPoly3")
# Child elements of <geometry> that carry no shape (tool extensions).
_GEOMETRY_EXTRAS = {"userData", "include", "dataQuality"}


@dataclass
class Cubic:
    """a + b*ds + c*ds^2 + d*ds^3 from ``s`` on (ds = s_query - s)."""

    s: float
    a: float
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0


@dataclass
class Geometry:
    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    params: dict[str, float | str] = field(default_factory=dict)


# roadMark types of OpenDRIVE 1.4-1.8. "grass", "edge" (a road edge, 1.6+) and "none" paint nothing;
# "custom" takes its shape from its <type> line definitions.
ROADMARK_TYPES = ("none", "solid", "broken", "solid solid", "solid broken", "broken solid", "broken broken",
                  "botts dots", "grass", "curb", "custom", "edge")


@dataclass
class MarkLine:
    """One ``<type><line>`` of a road mark; ``width`` 0 when the file leaves it out."""

    length: float
    space: float
    t_offset: float
    s_offset: float
    width: float = 0.0
    rule: str = ""


@dataclass
class RoadMark:
    """A ``<roadMark>``: valid from ``s_offset`` (relative to its lane section) to the next one."""

    s_offset: float
    type: str            # as in ROADMARK_TYPES (spaces kept)
    color: str           # lower case; "standard" when the file says so or nothing
    width: float         # 0 when missing
    weight: str = "standard"
    lines: list[MarkLine] = field(default_factory=list)


@dataclass
class Lane:
    id: int
    type: str
    widths: list[Cubic]  # s is the sOffset from the lane section start
    marks: list[RoadMark] = field(default_factory=list)  # sorted by s_offset


@dataclass
class LaneSection:
    s: float
    left: list[Lane]   # ids 1, 2, 3 ... (inner to outer)
    right: list[Lane]  # ids -1, -2, -3 ... (inner to outer)
    center_marks: list[RoadMark] = field(default_factory=list)  # road marks of the center lane 0


@dataclass
class Road:
    id: str
    name: str
    length: float
    junction: str
    geometries: list[Geometry]
    elevation: list[Cubic]
    superelevation: list[Cubic]
    lane_offset: list[Cubic]
    sections: list[LaneSection]
    objects: list[ObjectRecord] = field(default_factory=list)   # <objects> and <signals>, file order


@dataclass
class Header:
    name: str = ""
    vendor: str = ""
    date: str = ""
    rev: str = ""
    geo_reference: str = ""
    program: str = ""


@dataclass
class OpenDriveFile:
    path: Path
    header: Header
    roads: list[Road]
    junctions: list[str]


def _local(tag: object) -> str:
    """Tag without an XML namespace (OpenDRIVE 1.8 files may declare one)."""
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.name = path.name

    def fail(self, where: str, message: str) -> RoadtwinError:
        return RoadtwinError(f"{self.name}: {where}{': ' if where else ''}{message}")

    def num(self, el: ET.Element, key: str, where: str, default: float | None = None,
            limit: float = MAX_ABS) -> float:
        raw = el.get(key)
        if raw is None:
            if default is not None:
                return default
            raise self.fail(where, f"<{_local(el.tag)}> has no attribute {key!r}")
        try:
            value = float(raw.strip())
        except ValueError:
            raise self.fail(where, f"<{_local(el.tag)}> attribute {key}={raw!r} is not a number") from None
        if not math.isfinite(value):
            raise self.fail(where, f"<{_local(el.tag)}> attribute {key}={raw!r} is not finite")
        if abs(value) > limit:
            raise self.fail(where, f"<{_local(el.tag)}> attribute {key}={raw!r} is absurdly large "
                                   f"(at most {limit:g} in magnitude)")
        return value

    def cubic(self, el: ET.Element, where: str, s_key: str = "s", need_a: bool = False) -> Cubic:
        a = self.num(el, "a", where, None if need_a else 0.0, limit=MAX_WIDTH_M if need_a else MAX_ABS)
        return Cubic(self.num(el, s_key, where, limit=MAX_LENGTH_M), a, *(self.num(el, k, where, 0.0) for k in "bcd"))

    def cubics(self, parent: ET.Element | None, tag: str, where: str, s_key: str = "s",
               need_a: bool = False) -> list[Cubic]:
        if parent is None:
            return []
        recs = [self.cubic(el, where, s_key, need_a) for el in parent if _local(el.tag) == tag]
        return sorted(recs, key=lambda r: r.s)


def _child(el: ET.Element, tag: str) -> ET.Element | None:
    for c in el:
        if _local(c.tag) == tag:
            return c
    return None


def _children(el: ET.Element | None, tag: str) -> list[ET.Element]:
    return [] if el is None else [c for c in el if _local(c.tag) == tag]


def _road_at(path: Path, position: tuple[int, int]) -> str:
    """'road <id>' when a parse error lies inside a <road> element (best effort), else ''."""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines(keepends=True)
        line, col = position
        head = "".join(lines[:line - 1]) + (lines[line - 1][:col] if line - 1 < len(lines) else "")
    except (OSError, ValueError, TypeError, IndexError):
        return ""
    starts = list(re.finditer(r"<road\b[^>]*?\bid\s*=\s*[\"']([^\"']*)[\"']", head))
    if not starts or "</road>" in head[starts[-1].end():]:
        return ""
    return f"road {starts[-1].group(1)}"


def read_xodr(path: str | Path) -> OpenDriveFile:
    """Parse an OpenDRIVE file into records; raises RoadtwinError (one line) on any problem."""
    path = Path(path)
    rd = _Reader(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise rd.fail(_road_at(path, exc.position), f"not well-formed XML ({exc})") from None
    except OSError as exc:
        raise rd.fail("", f"cannot read ({exc.strerror or exc})") from None
    if _local(root.tag) != "OpenDRIVE":
        raise rd.fail("", f"not an OpenDRIVE file (root element <{_local(root.tag)}>, expected <OpenDRIVE>)")

    header = Header()
    h = _child(root, "header")
    if h is not None:
        geo = _child(h, "geoReference")
        user = _child(h, "userData")
        scene = _child(user, "vectorScene") if user is not None else None
        header = Header(name=h.get("name", ""), vendor=h.get("vendor", ""), date=h.get("date", ""),
                        rev=f"{h.get('revMajor', '1')}.{h.get('revMinor', '?')}",
                        geo_reference=" ".join((geo.text or "").split()) if geo is not None else "",
                        program=" ".join(filter(None, (scene.get("program", ""), scene.get("version", ""))))
                        if scene is not None else "")

    roads: list[Road] = []
    seen: set[str] = set()
    for i, el in enumerate(_children(root, "road")):
        rid = el.get("id")
        if rid is None or not rid.strip():
            raise rd.fail(f"road #{i + 1}", "has no id")
        rid = rid.strip()
        if rid in seen:
            raise rd.fail(f"road {rid}", "duplicate road id")
        seen.add(rid)
        roads.append(_read_road(rd, el, rid))
    if not roads:
        raise rd.fail("", "has no <road> elements")
    junctions = [j.get("id", "").strip() for j in _children(root, "junction")]
    return OpenDriveFile(path, header, roads, junctions)


def _read_road(rd: _Reader, el: ET.Element, rid: str) -> Road:
    where = f"road {rid}"
    length = rd.num(el, "length", where, limit=MAX_LENGTH_M)
    if length <= 0:
        raise rd.fail(where, f"length must be > 0, got {length}")
    junction = (el.get("junction") or "-1").strip() or "-1"

    plan = _child(el, "planView")
    geoms: list[Geometry] = []
    for g in _children(plan, "geometry"):
        gs = rd.num(g, "s", where)
        shapes = [c for c in g if _local(c.tag) not in _GEOMETRY_EXTRAS]
        if not shapes:
            raise rd.fail(where, f"<geometry s={g.get('s')}> has no shape element")
        kind = _local(shapes[0].tag)
        if kind not in GEOMETRY_KINDS:
            raise rd.fail(where, f"unknown geometry <{kind}> (known: {', '.join(GEOMETRY_KINDS)})")
        sh = shapes[0]
        if kind == "arc":
            params = {"curvature": rd.num(sh, "curvature", where)}
        elif kind == "spiral":
            params = {"curvStart": rd.num(sh, "curvStart", where), "curvEnd": rd.num(sh, "curvEnd", where)}
        elif kind == "poly3":
            params = {k: rd.num(sh, k, where, 0.0) for k in "abcd"}
        elif kind == "paramPoly3":
            params = {f"{k}{a}": rd.num(sh, f"{k}{a}", where, 0.0) for a in "UV" for k in "abcd"}
            p_range = sh.get("pRange", "normalized")
            if p_range not in ("normalized", "arcLength"):
                raise rd.fail(where, f"<paramPoly3> pRange={p_range!r} (expected normalized or arcLength)")
            params["pRange"] = p_range
        else:
            params = {}
        glen = rd.num(g, "length", where, limit=MAX_LENGTH_M)
        if glen < 0:
            raise rd.fail(where, f"<geometry s={g.get('s')}> has negative length {glen}")
        geoms.append(Geometry(gs, rd.num(g, "x", where), rd.num(g, "y", where), rd.num(g, "hdg", where, 0.0),
                              glen, kind, params))
    if not geoms:
        raise rd.fail(where, "has no <planView> geometry")
    geoms.sort(key=lambda g: g.s)
    _check_coverage(rd, where, geoms, length)
    geoms = [g for g in geoms if g.length > 1e-12] or geoms[:1]

    lanes_el = _child(el, "lanes")
    if lanes_el is None:
        raise rd.fail(where, "has no <lanes>")
    sections: list[LaneSection] = []
    for k, ls in enumerate(_children(lanes_el, "laneSection")):
        ls_where = f"{where}: laneSection {k}"
        left = _read_lanes(rd, _child(ls, "left"), ls_where, +1)
        right = _read_lanes(rd, _child(ls, "right"), ls_where, -1)
        center = _children(_child(ls, "center"), "lane")
        marks = _read_marks(rd, center[0], f"{ls_where}: lane 0") if center else []
        sections.append(LaneSection(rd.num(ls, "s", ls_where), left, right, marks))
    if not sections:
        raise rd.fail(where, "has no <laneSection>")
    sections.sort(key=lambda x: x.s)
    if not any(sec.left or sec.right for sec in sections):
        raise rd.fail(where, "has no lanes (only the center lane)")

    return Road(rid, el.get("name", ""), length, junction, geoms,
                rd.cubics(_child(el, "elevationProfile"), "elevation", where),
                rd.cubics(_child(el, "lateralProfile"), "superelevation", where),
                rd.cubics(lanes_el, "laneOffset", where), sections, read_road_objects(rd, el, where, length))


def _check_coverage(rd: _Reader, where: str, geoms: list[Geometry], length: float) -> None:
    """The plan view must run from s = 0 to the road's length without gaps: a geometry of zero
    length between two that meet is harmless (tools write them) and is dropped later, but one
    that leaves the road partly without a reference line is malformed."""
    tol = max(GAP_TOL_M, 1e-6 * length)
    end, last = 0.0, None
    for g in geoms:
        if g.s > end + tol:
            raise rd.fail(where, f"<planView> has a gap from s={end:g} to s={g.s:g} m{_zero_hint(last)}")
        end, last = max(end, g.s + g.length), g
    if end < length - tol:
        raise rd.fail(where, f"<planView> geometries end at s={end:g} m, short of the road length {length:g} m"
                             f"{_zero_hint(last)}")


def _zero_hint(g: Geometry | None) -> str:
    return f" (<geometry s={g.s:g}> has zero length)" if g is not None and g.length <= 1e-12 else ""


def _read_lanes(rd: _Reader, side: ET.Element | None, where: str, sign: int) -> list[Lane]:
    lanes = []
    for ln in _children(side, "lane"):
        raw = ln.get("id")
        try:
            lid = int(raw)
        except (TypeError, ValueError):
            raise rd.fail(where, f"<lane> id={raw!r} is not an integer") from None
        if lid == 0 or (lid > 0) != (sign > 0):
            raise rd.fail(where, f"lane {lid} is on the wrong side ({'left' if sign > 0 else 'right'} lanes have "
                                 f"{'positive' if sign > 0 else 'negative'} ids)")
        lw = f"{where}: lane {lid}"
        widths = rd.cubics(ln, "width", lw, s_key="sOffset", need_a=True)  # the width itself: no default
        if not widths:
            if _children(ln, "border"):
                raise rd.fail(lw, "uses <border> records, which are not supported (only <width>)")
            raise rd.fail(lw, "has no <width> records")
        lanes.append(Lane(lid, ln.get("type", "none"), widths, _read_marks(rd, ln, lw)))
    lanes.sort(key=lambda x: abs(x.id))
    ids = [abs(x.id) for x in lanes]
    if ids != list(range(1, len(ids) + 1)):
        raise rd.fail(where, f"lane ids {sorted(x.id for x in lanes)} are not consecutive from the center lane")
    return lanes


def _read_marks(rd: _Reader, lane: ET.Element, where: str) -> list[RoadMark]:
    """A lane's road marks, sorted by sOffset (a stable sort: files list them in any order)."""
    marks = []
    for el in _children(lane, "roadMark"):
        raw = " ".join((el.get("type") or "").split())
        if raw not in ROADMARK_TYPES:
            raise rd.fail(where, f"<roadMark> type={el.get('type')!r} is not an OpenDRIVE road mark type "
                                 f"(known: {', '.join(ROADMARK_TYPES)})")
        s_offset = rd.num(el, "sOffset", where, 0.0)
        width = rd.num(el, "width", where, 0.0)
        if s_offset < 0 or width < 0:
            raise rd.fail(where, f"<roadMark> sOffset and width must be >= 0, got sOffset={s_offset:g} "
                                 f"width={width:g}")
        lines = []
        type_el = _child(el, "type")
        for ln in _children(type_el, "line"):
            line = MarkLine(rd.num(ln, "length", where, 0.0), rd.num(ln, "space", where, 0.0),
                            rd.num(ln, "tOffset", where, 0.0), rd.num(ln, "sOffset", where, 0.0),
                            rd.num(ln, "width", where, 0.0), ln.get("rule", ""))
            if min(line.length, line.space, line.s_offset, line.width) < 0:
                raise rd.fail(where, "<roadMark><type><line> length, space, sOffset and width must be >= 0")
            lines.append(line)
        marks.append(RoadMark(s_offset, raw, (el.get("color") or "standard").strip().lower() or "standard",
                              width, (el.get("weight") or "standard").strip(), lines))
    marks.sort(key=lambda m: m.s_offset)
    return marks
