"""OpenDRIVE (.xodr) -> roadtwin TownLayout.

What a layout gets from a map:

- One planar :class:`RoadSegment` per lane, per lane section, per piece of at most
  ``max_segment_length_m`` (pieces of equal length, CARLA-like), for roads outside junctions.
  Outline = the lane's inner border followed by its outer border, both sampled at the same s
  values (every ``sample_step_m`` plus every geometry, lane-section, laneOffset and width-record
  boundary). Neighbouring lanes use the very same border array and neighbouring pieces the very
  same cross-section, so the town mesh is watertight. Id ``r<road>_ls<k>_l<m|p><|lane|>_<piece>``,
  kind = the lane type, attributes road / lane / laneSection / junction, centerline = the lane's
  centre line in its direction of travel (right-hand traffic: negative ids along +s).
- Lane widths are clamped at 0 and widths below 1 micrometre are set to exactly 0; a lane that
  narrows to zero keeps a pointed tip (no zero-width quads) and a lane that is zero over a
  stretch splits into separate pieces, so every triangle has area and every segment is one
  polygon.
- Junctions: connecting roads overlap each other, so their lanes are *not* emitted one by one
  (one spot would get its defect twice). Per junction, the union of its connecting roads'
  drivable lanes becomes one segment ``junction_<id>`` of kind "junction" (no centerline), and the
  remaining lane kinds there (sidewalk, shoulder ...) become ``junction_<id>_<kind>_<n>``
  segments with the drivable area and each other subtracted. Holes of up to 25 m^2 enclosed by
  a junction's lanes are filled into the junction surface: maps leave such uncovered asphalt
  (CARLA Town01's corner sidewalks are ~5 m radius arcs, its turning lanes ~8.5 m: a crescent
  between them belongs to no lane). The connecting lanes' centre lines
  are not stored in the layout (they are routes, not surfaces); :func:`load_network` returns
  them in ``OpenDriveNetwork.connecting_centerlines``.
- Elevation: segments are planar; ``layout.terrain`` holds (x, y, z) at the lane border points
  every ``terrain_step_m`` along s: z = elevation(s) + t * sin(superelevation(s)), with the point
  placed at t * cos(superelevation(s)) across the reference line (the cross section is rotated
  rigidly by the roll angle, as the standard and libOpenDRIVE do; the lane ``level`` flag is
  ignored). The composer restores elevation from these samples through its k-d tree.
- Rules: kinds ("driving", "junction"), flat surface, cdt merger, ``defect_count`` defects
  (1000 by default, like the paper's Town01) capped at one per 20 m^2 of driving + junction
  area so a small map stays composable.

- Road marks: every lane's ``<roadMark>`` records (junction roads included) become
  :class:`LaneMarking` curves in ``layout.markings``. A mark holds from its sOffset to the next
  mark's sOffset (or the lane section end); it lies on the lane's outer border (lane 0: the
  reference line + laneOffset), moved sideways by its ``<line tOffset>`` if it has one, sampled
  at ``sample_step_m`` on the very border points the segments use, in the lane's travel
  direction. Types "none", "grass" and "edge" paint nothing and are skipped; "curb" is kept as
  data. Standard dash/gap/width where the file gives no ``<type>`` lines: see
  :mod:`roadtwin_opendrive._marks`. Consecutive marks of one lane with the same style (also across
  lane sections, where the lane keeps its id and the curves join) become one curve. The marks
  are the file's: two connecting roads of a junction that share a reference line (CARLA does
  this) both carry their centre line, so such a line is there twice, on the same points.
  Id ``r<road>_ls<k>_<c0|lane tag>_<j>`` (k, j: lane section and mark where the curve starts).

- Objects and signals: every road's ``<object>``s (with their ``<repeat>``s) and ``<signal>``s
  become :class:`MapObject`s in ``layout.objects``, posed in the world frame by the road's
  reference line (:mod:`roadtwin_opendrive._objects`); compose turns them into props.

Supported: geometry line / arc / spiral / poly3 / paramPoly3, elevationProfile, superelevation,
laneOffset, lane sections with width records, road marks (not their ``<sway>`` or
``<explicit>`` geometry), objects and signals (not their outlines). Not supported (refused with a
clear message): lane <border> records. Ignored: lane heights, crossfall, shapes, object outlines.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np
import shapely
import triangle
from shapely.geometry import MultiPolygon, Polygon

from roadtwin_core import (ComposeRules, LaneMarking, RoadSegment, RoadtwinError, TownLayout, check_params, field,
                           make_params, triangle_areas)
from roadtwin_core.usd import safe_prim_name

from ._marks import MarkStyle, mark_style
from ._objects import road_objects
from ._refline import ReferenceLine, eval_cubics
from ._xodr import OpenDriveFile, Road, read_xodr

DRIVABLE = ("driving", "bidirectional", "entry", "exit", "onRamp", "offRamp", "connectingRamp", "stop")
# Order in which the non-drivable parts of a junction are carved out of what is left.
_JUNCTION_ORDER = ("shoulder", "border", "restricted", "parking", "biking", "median", "curb", "sidewalk")
_ZERO_WIDTH = 1e-6       # m: narrower than this is exactly zero
_MIN_JUNCTION_PART = 0.05  # m^2: smaller leftovers of the junction boolean ops are dropped
_SNAP = 1e-4             # m: grid the junction polygons are snapped to after the union
_M2_PER_DEFECT = 20.0
_MAX_JUNCTION_GAP = 25.0   # m^2: holes enclosed by a junction's lanes up to this size become junction surface


@dataclass
class OpenDriveParams:
    max_segment_length_m: float = field(25.0, lo=0.5, doc="split lanes into pieces of at most this length (CARLA-like)")
    sample_step_m: float = field(0.5, lo=0.01, hi=10.0, doc="tessellation step along s")
    include_kinds: tuple[str, ...] = field((), doc="lane types to emit; empty: every type but 'none'")
    terrain_step_m: float = field(2.0, lo=0.01, doc="spacing along s of the terrain (elevation) samples")
    defect_count: int = field(1000, lo=0, doc="rules: defects to place (capped at one per 20 m^2 of driveway)")
    attribution: str = field("", doc="attribution text stored in the layout (default: from the file header)")


@dataclass
class OpenDriveNetwork:
    """An imported map: the layout plus what a layout does not hold."""

    layout: TownLayout
    road_count: int
    junction_count: int
    connecting_centerlines: dict[str, np.ndarray] = dc_field(default_factory=dict)
    lane_section_count: int = 0


def _safe(text: str) -> str:
    """An id piece made of prim-name characters (it may start with a digit: it is a suffix)."""
    return safe_prim_name(text, empty="", lead="")


def _inner_id(lane_id: int) -> int:
    """The lane whose outer border is this lane's inner border (0: the center lane)."""
    return lane_id - 1 if lane_id > 0 else lane_id + 1


def _lane_tag(lane_id: int) -> str:
    return f"l{'m' if lane_id < 0 else 'p'}{abs(lane_id)}" if lane_id else "c0"


def _span(s: np.ndarray, xy: np.ndarray, a: float, b: float) -> np.ndarray:
    """The stretch s in [a, b] of a border sampled at s: interpolated ends plus the samples between."""
    inside = (s > a + 1e-6) & (s < b - 1e-6)
    ends = np.array([[np.interp(v, s, xy[:, 0]), np.interp(v, s, xy[:, 1])] for v in (a, b)])
    return np.concatenate([ends[:1], xy[inside], ends[1:]])


@dataclass
class _MarkPiece:
    """A stretch of one road mark, points along +s (reversed for left lanes at the end)."""

    id: str
    road: str
    lane: int
    style: MarkStyle
    points: np.ndarray
    s_length: float

    def marking(self) -> LaneMarking:
        st, pts = self.style, self.points
        if self.lane > 0:
            pts = pts[::-1]
        phase = 0.0
        if st.dash_m > 0:
            length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
            first = st.first_dash_s * length / max(self.s_length, 1e-9)  # s -> along the curve
            # against s the pattern is mirrored: where the last dash (in s) ends is the first start
            phase = (length - first - st.dash_m) % (st.dash_m + st.gap_m) if self.lane > 0 else first
        return LaneMarking(self.id, st.marking_type, st.color, st.width_m, pts, st.dash_m, st.gap_m, phase,
                           st.spacing_m)


def _triangulate(ring: np.ndarray, holes: list[np.ndarray] = ()) -> tuple[np.ndarray, np.ndarray]:
    loops = [ring, *holes]
    verts = np.concatenate(loops)
    segs, start = [], 0
    for loop in loops:
        n = len(loop)
        i = np.arange(n) + start
        segs.append(np.column_stack([i, np.roll(i, -1)]))
        start += n
    data = {"vertices": verts, "segments": np.concatenate(segs)}
    if holes:
        data["holes"] = np.array([Polygon(h).representative_point().coords[0] for h in holes])
    t = triangle.triangulate(data, "pQ")
    v, f = t["vertices"], t["triangles"].astype(np.int64)
    a = v[f]
    area2 = (a[:, 1, 0] - a[:, 0, 0]) * (a[:, 2, 1] - a[:, 0, 1]) - (a[:, 1, 1] - a[:, 0, 1]) * (a[:, 2, 0] - a[:, 0, 0])
    f[area2 < 0] = f[area2 < 0][:, ::-1]
    return v, f


def _check_strip(seg_id: str, ring: np.ndarray, v: np.ndarray, f: np.ndarray) -> None:
    """What RoadSegment.polygon() demands, checked cheaply: a simple outline triangulated without
    new vertices gives non-overlapping triangles; they must also all have area."""
    if len(v) != len(ring) or not shapely.is_valid(shapely.polygons(ring)):
        raise RoadtwinError(f"road segment {seg_id!r}: outline intersects itself")
    a = v[f]
    area2 = (a[:, 1, 0] - a[:, 0, 0]) * (a[:, 2, 1] - a[:, 0, 1]) - (a[:, 1, 1] - a[:, 0, 1]) * (a[:, 2, 0] - a[:, 0, 0])
    if not (area2 > 1e-12).all():
        raise RoadtwinError(f"road segment {seg_id!r}: has degenerate (zero-area) triangles")


def _lane_components(inner: np.ndarray, outer: np.ndarray, width: np.ndarray):
    """(first, last, ring) for each stretch of non-zero width; zero-width ends become tips."""
    n = len(width)
    open_ = width > 0.0
    idx = np.flatnonzero(open_)
    if len(idx) == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    firsts = idx[np.r_[0, breaks + 1]]
    lasts = idx[np.r_[breaks, len(idx) - 1]]
    out = []
    for a, b in zip(firsts, lasts):
        a2, b2 = max(a - 1, 0), min(b + 1, n - 1)
        keep = open_[a2:b2 + 1]
        ring = np.concatenate([inner[a2:b2 + 1], outer[a2:b2 + 1][keep][::-1]])
        # untangled borders repeat their crossing point: drop consecutive duplicates
        dup = np.all(ring == np.roll(ring, 1, axis=0), axis=1)
        ring = ring[~dup]
        if len(ring) >= 3:
            out.append((a2, b2, ring))
    return out


def _crossings(p: np.ndarray) -> tuple[int, int, np.ndarray] | None:
    """First self-crossing of a polyline: (i, j, point) for segments i < j - 1 (largest j)."""
    a, d = p[:-1], p[1:] - p[:-1]
    n = len(a)
    for i in range(n - 2):
        j = np.arange(i + 2, n)
        r = a[j] - a[i]
        den = d[i, 0] * d[j, 1] - d[i, 1] * d[j, 0]
        ok = np.abs(den) > 1e-15
        den = np.where(ok, den, 1.0)
        t = (r[:, 0] * d[j, 1] - r[:, 1] * d[j, 0]) / den
        u = (r[:, 0] * d[i, 1] - r[:, 1] * d[i, 0]) / den
        hit = ok & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
        if hit.any():
            k = int(np.flatnonzero(hit)[-1])
            return i, int(j[k]), a[i] + t[k] * d[i]
    return None


def untangle(points: np.ndarray, max_loops: int = 100) -> np.ndarray:
    """Remove the loops of a self-crossing border (an offset larger than the curve radius).

    The points of each loop collapse onto its crossing point, so the array keeps one point per
    s sample (cross sections stay paired and shared) and the border becomes a simple line.
    """
    if shapely.is_simple(shapely.linestrings(points)):
        return points
    p = points.copy()
    for _ in range(max_loops):
        keep = np.r_[True, np.any(p[1:] != p[:-1], axis=1)]
        first = np.flatnonzero(keep)            # original index of each distinct point
        hit = _crossings(p[keep])
        if hit is None:
            return p
        i, j, x = hit
        lo = first[i + 1]
        hi = first[j + 1] if j + 1 < len(first) else len(p)
        p[lo:hi] = x
    return p


@dataclass
class _Section:
    k: int
    s: np.ndarray
    cuts: np.ndarray            # indices into s where pieces start/end
    x: np.ndarray
    y: np.ndarray
    nx: np.ndarray              # unit normal (left of the reference line) times cos(superelevation)
    ny: np.ndarray
    z0: np.ndarray              # elevation(s)
    sin_sf: np.ndarray
    borders: dict[int, np.ndarray]  # lane id -> t of its outer border; 0 -> laneOffset (center)
    _xy: dict[int, np.ndarray] = dc_field(default_factory=dict)

    def points(self, t: np.ndarray) -> np.ndarray:
        return np.column_stack([self.x + t * self.nx, self.y + t * self.ny])

    def border_xy(self, lane_id: int) -> np.ndarray:
        """Border points of one border, untangled; computed once so both lanes share them."""
        if lane_id not in self._xy:
            self._xy[lane_id] = untangle(self.points(self.borders[lane_id]))
        return self._xy[lane_id]


class OpenDriveImporter:
    name = "opendrive"
    description = "OpenDRIVE 1.4-1.8 road networks (.xodr): lanes as segments, junctions merged, road marks kept"
    Params = OpenDriveParams

    def load(self, path: str | Path, params: OpenDriveParams | dict | None = None) -> TownLayout:
        return load_network(path, params).layout


def _params(params, owner: str) -> OpenDriveParams:
    if params is None:
        return OpenDriveParams()
    if isinstance(params, dict):
        return make_params(OpenDriveParams, params, owner)
    return check_params(params, owner)


def load_network(path: str | Path, params: OpenDriveParams | dict | None = None) -> OpenDriveNetwork:
    """Import a map; see the module docstring for what comes out."""
    path = Path(path)
    p = _params(params, f"importer opendrive ({path.name})")
    odr = read_xodr(path)
    return _Builder(odr, p).build()


class _Builder:
    def __init__(self, odr: OpenDriveFile, p: OpenDriveParams) -> None:
        self.odr, self.p = odr, p
        self.name = odr.path.name
        self.kinds = set(p.include_kinds) if p.include_kinds else None
        self.segments: list[RoadSegment] = []
        self.terrain: list[np.ndarray] = []
        self.junction_polys: dict[str, dict[str, list[Polygon]]] = {}
        self.junction_roads: dict[str, list[str]] = {}
        self.centerlines: dict[str, np.ndarray] = {}
        self.road_tags: dict[str, str] = {}
        self.n_sections = 0
        self.marks: list[_MarkPiece] = []
        self.objects: list = []

    def fail(self, road: Road, message: str) -> RoadtwinError:
        return RoadtwinError(f"{self.name}: road {road.id}: {message}")

    def wanted(self, kind: str) -> bool:
        return kind != "none" and (self.kinds is None or kind in self.kinds)

    # ---- sampling --------------------------------------------------------------------------
    def sections(self, road: Road, ref: ReferenceLine) -> list[_Section]:
        p = self.p
        in_junction = road.junction != "-1"
        out: list[_Section] = []
        prev_end: np.ndarray | None = None
        starts = [sec.s for sec in road.sections]
        for k, sec in enumerate(road.sections):
            s0 = max(sec.s, 0.0)
            s1 = min(starts[k + 1] if k + 1 < len(starts) else road.length, road.length)
            if s1 - s0 < 1e-6:
                prev_end = None
                continue
            length = s1 - s0
            n_pieces = 1 if in_junction else max(1, math.ceil(length / p.max_segment_length_m - 1e-9))
            cuts = s0 + length * np.arange(n_pieces + 1) / n_pieces
            cuts[-1] = s1
            extra = [*ref.boundaries(), *(r.s for r in road.lane_offset),
                     *(s0 + w.s for ln in sec.left + sec.right for w in ln.widths)]
            extra = np.array([e for e in extra if s0 < e < s1])
            if len(extra):
                extra = np.unique(extra)
                far = np.min(np.abs(extra[:, None] - cuts[None, :]), axis=1) > 1e-3
                extra = extra[far]
                if len(extra) > 1:
                    extra = extra[np.r_[True, np.diff(extra) > 1e-3]]
            must = np.sort(np.concatenate([cuts, extra]))
            parts = [must[:1]]
            for a, b in zip(must[:-1], must[1:]):
                m = max(1, math.ceil((b - a) / p.sample_step_m - 1e-9))
                seg = a + (b - a) * np.arange(1, m + 1) / m
                seg[-1] = b
                parts.append(seg)
            s = np.concatenate(parts)
            cut_idx = np.searchsorted(s, cuts)
            x, y, h = ref(s)
            sf = eval_cubics(road.superelevation, s)
            cos_sf = np.cos(sf)
            nx, ny = -np.sin(h) * cos_sf, np.cos(h) * cos_sf
            off = eval_cubics(road.lane_offset, s)
            borders = {0: off}
            for side, sign in ((sec.left, 1.0), (sec.right, -1.0)):
                cum = off
                for lane in side:
                    w = eval_cubics(lane.widths, s - sec.s)
                    w = np.where(w > _ZERO_WIDTH, w, 0.0)
                    cum = cum + sign * w
                    borders[lane.id] = cum
            if prev_end is not None:  # make consecutive lane sections share their cross section
                for t in borders.values():
                    d = np.abs(prev_end - t[0])
                    j = int(np.argmin(d))
                    if d[j] < 1e-6:
                        t[0] = prev_end[j]
            prev_end = np.array([t[-1] for t in borders.values()])
            out.append(_Section(k, s, cut_idx, x, y, nx, ny, eval_cubics(road.elevation, s), np.sin(sf), borders))
        return out

    # ---- per road --------------------------------------------------------------------------
    def road(self, road: Road) -> None:
        ref = ReferenceLine(road.geometries)
        tag = _safe(road.id)
        if tag in self.road_tags.values():
            tag = f"{tag}_{len(self.road_tags)}"
        self.road_tags[road.id] = tag
        in_junction = road.junction != "-1"
        if in_junction:
            self.junction_roads.setdefault(road.junction, []).append(road.id)
        open_marks: dict[int, _MarkPiece] = {}  # lane id -> its last mark piece on this road
        self.objects += road_objects(road, ref)
        for sec in self.sections(road, ref):
            self.n_sections += 1
            self.add_terrain(sec)
            self.road_marks(road, sec, tag, open_marks)
            lanes = {ln.id: ln for ln in road.sections[sec.k].left + road.sections[sec.k].right}
            for lid, lane in sorted(lanes.items(), key=lambda kv: (kv[0] < 0, abs(kv[0]))):
                if not self.wanted(lane.type) and not (in_junction and lane.type in DRIVABLE):
                    continue
                t_in = sec.borders[_inner_id(lid)]
                t_out = sec.borders[lid]
                width = np.abs(t_out - t_in)
                base = f"r{tag}_ls{sec.k}_{_lane_tag(lid)}"
                if in_junction:
                    self.junction_lane(road, sec, lane.type, lid, t_in, t_out, width, base)
                else:
                    self.lane_segments(road, sec, lane.type, lid, t_in, t_out, width, base)

    def road_marks(self, road: Road, sec: _Section, tag: str, open_marks: dict[int, _MarkPiece]) -> None:
        """Mark pieces of one lane section; a piece that continues the lane's last one joins it."""
        rec = road.sections[sec.k]
        s_end = float(sec.s[-1])
        for lid, marks in [(0, rec.center_marks), *((ln.id, ln.marks) for ln in rec.left + rec.right)]:
            for j, mark in enumerate(marks):
                a = max(rec.s + mark.s_offset, float(sec.s[0]))
                b = min(rec.s + marks[j + 1].s_offset if j + 1 < len(marks) else s_end, s_end)
                style = mark_style(mark, lid > 0)
                if b - a < 1e-6 or style is None:
                    continue
                if style.t_shift:
                    xy = untangle(sec.points(sec.borders[lid] + style.t_shift))
                else:
                    xy = sec.border_xy(lid)
                pts = _span(sec.s, xy, a, b)
                last = open_marks.get(lid)
                if (last is not None and last.style == style and style.first_dash_s == 0
                        and np.abs(last.points[-1] - pts[0]).max() < 1e-6):
                    last.points = np.concatenate([last.points, pts[1:]])
                    last.s_length += b - a
                    continue
                piece = _MarkPiece(f"r{tag}_ls{sec.k}_{_lane_tag(lid)}_{j}", road.id, lid, style, pts, b - a)
                self.marks.append(piece)
                open_marks[lid] = piece
            if not marks:
                open_marks.pop(lid, None)

    def lane_segments(self, road, sec: _Section, kind, lid, t_in, t_out, width, base) -> None:
        inner, outer = sec.border_xy(_inner_id(lid)), sec.border_xy(lid)
        mid = sec.points(0.5 * (t_in + t_out))
        piece = 0
        for i0, i1 in zip(sec.cuts[:-1], sec.cuts[1:]):
            sl = slice(i0, i1 + 1)
            for a, b, ring in _lane_components(inner[sl], outer[sl], width[sl]):
                v, f = _triangulate(ring)
                center = mid[i0 + a:i0 + b + 1]
                center = center[::-1] if lid > 0 else center
                seg_id = f"{base}_{piece}"
                piece += 1
                try:
                    seg = RoadSegment(seg_id, kind, v, f, center,
                                      {"road": road.id, "lane": int(lid), "laneSection": int(sec.k),
                                       "junction": road.junction})
                    _check_strip(seg_id, ring, v, f)
                except RoadtwinError as exc:
                    raise self.fail(road, f"lane {lid} (laneSection {sec.k}, s {sec.s[i0 + a]:.2f}.."
                                          f"{sec.s[i0 + b]:.2f}): {str(exc).split(': ', 1)[-1]}") from None
                self.segments.append(seg)

    def junction_lane(self, road, sec: _Section, kind, lid, t_in, t_out, width, base) -> None:
        inner, outer = sec.border_xy(_inner_id(lid)), sec.border_xy(lid)
        polys = self.junction_polys.setdefault(road.junction, {})
        key = "junction" if kind in DRIVABLE else kind
        for a, b, ring in _lane_components(inner, outer, width):
            poly = Polygon(ring)
            if not poly.is_valid:
                poly = shapely.make_valid(poly)
            polys.setdefault(key, []).append(poly)
            if kind in DRIVABLE:
                center = sec.points(0.5 * (t_in + t_out))[a:b + 1]
                self.centerlines[f"{base}_{len(self.centerlines)}"] = center[::-1] if lid > 0 else center

    def add_terrain(self, sec: _Section) -> None:
        grid = np.arange(sec.s[0], sec.s[-1], self.p.terrain_step_m)
        idx = np.unique(np.r_[np.searchsorted(sec.s, grid), len(sec.s) - 1])
        for t in sec.borders.values():
            ti = t[idx]
            xy = sec.points(t)[idx]
            self.terrain.append(np.column_stack([xy, sec.z0[idx] + ti * sec.sin_sf[idx]]))

    # ---- junctions -------------------------------------------------------------------------
    def junctions(self) -> None:
        for jid in sorted(self.junction_polys, key=_natural):
            polys = self.junction_polys[jid]
            everything = shapely.union_all([q for qs in polys.values() for q in qs])
            gaps = [Polygon(r) for g in getattr(everything, "geoms", [everything]) if isinstance(g, Polygon)
                    for r in g.interiors]
            gaps = [g for g in gaps if g.area <= _MAX_JUNCTION_GAP]
            if gaps and "junction" in polys:  # asphalt that no lane covers (see the module docstring)
                polys = {**polys, "junction": polys["junction"] + gaps}
            taken = None
            order = ["junction", *_JUNCTION_ORDER, *sorted(set(polys) - {"junction", *_JUNCTION_ORDER})]
            for kind in order:
                if kind not in polys:
                    continue
                area = shapely.union_all(polys[kind])
                if taken is not None:
                    area = area.difference(taken)
                taken = area if taken is None else shapely.union_all([taken, area])
                parts = _clean(area)
                for n, part in enumerate(parts):
                    if kind == "junction":
                        seg_id = f"junction_{_safe(jid)}" + (f"_{n}" if n else "")
                    else:
                        seg_id = f"junction_{_safe(jid)}_{kind}_{n}"
                    rings = [np.asarray(r.coords)[:-1] for r in (part.exterior, *part.interiors)]
                    v, f = _triangulate(rings[0], rings[1:])
                    try:
                        seg = RoadSegment(seg_id, kind, v, f, None,
                                          {"junction": jid, "roads": ",".join(self.junction_roads.get(jid, []))})
                        seg.polygon()
                    except RoadtwinError as exc:
                        raise RoadtwinError(f"{self.name}: junction {jid}: {str(exc).split(': ', 1)[-1]}") from None
                    self.segments.append(seg)

    # ---- all -------------------------------------------------------------------------------
    def build(self) -> OpenDriveNetwork:
        for road in self.odr.roads:
            self.road(road)
        self.junctions()
        if not self.segments:
            raise RoadtwinError(f"{self.name}: no lanes of the included kinds to import")
        odr, h = self.odr, self.odr.header
        drive = sum(float(triangle_areas(s.vertices, s.faces).sum()) for s in self.segments
                    if s.kind in ("driving", "junction"))
        count = min(self.p.defect_count, int(drive // _M2_PER_DEFECT))
        # A 1 m road mesh: elevation samples are terrain_step_m (2 m) apart, so a finer mesh
        # adds triangles without adding shape.
        rules = ComposeRules(defect_count=count, surface="flat", merger="cdt", kinds=("driving", "junction"),
                             road_edge_m=1.0)
        attribution = self.p.attribution or " ".join(filter(None, [
            f"OpenDRIVE {h.rev} map {h.name or odr.path.stem!r}",
            f"by {h.vendor}" if h.vendor else "", f"({h.program})" if h.program else "",
            f"dated {h.date}" if h.date else ""]))
        meta = {"geoReference": h.geo_reference, "source": odr.path.name, "attribution": attribution,
                "sourceRoads": str(len(odr.roads)), "sourceJunctions": str(len(odr.junctions))}
        name = _safe(odr.path.stem) or "Town"
        name = name if not name[0].isdigit() else f"_{name}"
        terrain = np.concatenate(self.terrain) if self.terrain else None
        markings = []
        for piece in self.marks:
            try:
                markings.append(piece.marking())
            except RoadtwinError as exc:
                raise RoadtwinError(f"{self.name}: road {piece.road}: lane {piece.lane} road mark {piece.id}: "
                                   f"{str(exc).split(': ', 1)[-1]}") from None
        layout = TownLayout(name, self.segments, rules, str(odr.path), terrain, [], meta, markings, self.objects)
        return OpenDriveNetwork(layout, len(odr.roads), len(odr.junctions), self.centerlines, self.n_sections)


def _natural(text: str):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", text)]


def _clean(geom) -> list[Polygon]:
    """Polygons of a union/difference result, snapped and simplified for a clean triangulation."""
    geom = shapely.set_precision(geom, _SNAP)
    geom = geom.simplify(_SNAP, preserve_topology=True)
    out = []
    parts = geom.geoms if hasattr(geom, "geoms") else [geom]
    for part in parts:
        if not isinstance(part, (Polygon, MultiPolygon)):
            continue
        for poly in (part.geoms if isinstance(part, MultiPolygon) else [part]):
            if poly.area < _MIN_JUNCTION_PART:
                continue
            holes = [r for r in poly.interiors if Polygon(r).area >= _MIN_JUNCTION_PART]
            poly = Polygon(poly.exterior, holes)
            out.append(shapely.orient_polygons(poly) if hasattr(shapely, "orient_polygons") else poly)
    out.sort(key=lambda q: -q.area)
    return out
