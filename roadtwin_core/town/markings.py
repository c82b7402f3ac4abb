"""Lane-marking meshes: the layout's marking curves painted on the merged, elevated road.

Per :class:`~roadtwin_core.model.LaneMarking`, each painted line (``LaneMarking.lines()``) becomes
2D paint polygons: every dash is its own piece (a substring of the boundary polyline, shifted
sideways by the line's offset with shapely's ``offset_curve``, buffered to the line width with
flat caps), botts dots are small discs. The paint is then cut where a defect removed it (minus
the union of the defect footprints, grown by ``cut_margin_m`` so no paint hangs over a rim),
clipped to the road outline, triangulated with Triangle (boundary and interior points at most
``spacing_m`` apart) and draped: every vertex sits ``lift_m`` above the merged road surface
under it (a vertical ray per vertex, :func:`roadtwin_core.geometry.vertical_ray_hits`).

The road's own edges that cross the paint are constraint segments of that triangulation, so
each paint triangle lies inside one road triangle and the draped paint is exactly parallel to
the road. Without them a paint triangle is a chord over a creased road and dips under it near
defect rims and on rough roads (measured: 2 mm under an ISO 8608 class D road).

Dash positions are measured along the boundary polyline itself (``phase_m`` + k (dash + gap)),
so both lines of a double marking break at the same stations. Curbs are kerbs, not paint: they
draw nothing. Pure numpy/shapely/triangle, no USD.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
import triangle
from scipy.spatial import cKDTree
from shapely.geometry import LineString, Polygon
from shapely.ops import substring

from ..errors import RoadtwinError
from ..geometry import vertical_ray_hits_pairs
from ..model import LaneMarking, MergedSegment, Placement, RoadSegment

LIFT_M = 0.005           # paint floats this far above the road (no z-fighting, no visible gap)
CUT_MARGIN_M = 0.02      # paint stops this far outside a defect footprint
SPACING_M = 0.5          # most distance between neighbouring marking vertices (draping resolution)
BOTTS_PITCH_M = 1.2      # dot pitch when a botts-dots marking gives no dash/gap (4 ft, Caltrans)
_CELL_M = 2.0            # spatial bucket of the height lookup
_MIN_AREA_M2 = 1e-6      # slivers left by the cut below this are dropped
_GRID_M = 1e-6           # snap-rounding grid of the paint/road-edge overlay


@dataclass
class MarkingMesh:
    """One marking's paint, draped: world vertices (N,3) and triangles (M,3)."""

    id: str
    marking_type: str
    color: str
    vertices: np.ndarray
    faces: np.ndarray


def dash_intervals(length_m: float, dash_m: float, gap_m: float, phase_m: float = 0.0) -> list[tuple[float, float]]:
    """Stations ``(start, end)`` along a polyline of ``length_m`` that carry paint.

    Solid (``dash_m == 0``): the whole line. Broken: dashes start at ``phase_m + k (dash + gap)``;
    the last one is cut at the line's end."""
    if dash_m <= 0:
        return [(0.0, length_m)]
    pitch = dash_m + gap_m
    starts = phase_m + pitch * np.arange(int(np.ceil(max(length_m - phase_m, 0.0) / pitch)))
    return [(float(s), float(min(s + dash_m, length_m))) for s in starts if min(s + dash_m, length_m) - s > 1e-6]


def line_paint(marking: LaneMarking) -> list[Polygon]:
    """The marking's paint as separate 2D pieces (one per dash or dot), before any cut."""
    base = LineString(marking.points)
    length = base.length
    half = marking.width_m / 2
    pieces: list[Polygon] = []
    for offset, dash, gap in marking.lines():
        if marking.marking_type == "botts_dots":
            pitch = dash + gap if dash + gap > 0 else BOTTS_PITCH_M
            count = int(np.floor(max(length - marking.phase_m, 0.0) / pitch + 1e-9)) + 1  # a dot on the end too
            stations = marking.phase_m + pitch * np.arange(count)
            for s in stations:
                pieces.append(base.interpolate(float(s)).buffer(half, quad_segs=4))
            continue
        for s0, s1 in dash_intervals(length, dash, gap, marking.phase_m):
            centre = substring(base, s0, s1)
            if offset:
                centre = centre.offset_curve(offset, join_style="mitre", mitre_limit=2.0)
            for part in getattr(centre, "geoms", [centre]):
                if part.length > 1e-6:
                    pieces.append(part.buffer(half, cap_style="flat", join_style="mitre", mitre_limit=2.0))
    return [p for p in pieces if not p.is_empty]


class RoadSurface:
    """The merged road: its outline (for clipping) and, per marking, a :class:`RoadPatch` of the
    triangles near the paint (built per marking so memory stays small on big towns)."""

    def __init__(self, segments: list[RoadSegment], merged: list[MergedSegment]) -> None:
        self.polygons = [s.polygon() for s in segments]
        self.outline_tree = shapely.STRtree(self.polygons)
        self.merged = merged
        self._centroids: dict[int, tuple[np.ndarray, float]] = {}

    def near(self, geom) -> np.ndarray:
        """Indices of the segments whose outline touches ``geom``."""
        return np.sort(self.outline_tree.query(geom, predicate="intersects"))

    def outline(self, segment_ids: np.ndarray) -> shapely.Geometry:
        return shapely.union_all([self.polygons[i] for i in segment_ids])

    def _segment_index(self, i: int) -> tuple[np.ndarray, float]:
        """(triangle centroids (T, 2), longest edge) of segment ``i``, computed once: a long
        marking crosses many segments and a segment carries many markings."""
        if i not in self._centroids:
            m = self.merged[i]
            xy = m.vertices[:, :2]
            a, b, c = xy[m.faces[:, 0]], xy[m.faces[:, 1]], xy[m.faces[:, 2]]
            reach = float(np.sqrt(max(((b - a) ** 2).sum(1).max(), ((c - b) ** 2).sum(1).max(),
                                      ((a - c) ** 2).sum(1).max()))) if len(m.faces) else 0.0
            self._centroids[i] = ((a + b + c) / 3.0, reach)
        return self._centroids[i]

    def patch(self, segment_ids: np.ndarray, paint) -> "RoadPatch":
        """The triangles of those segments that may touch ``paint``: those whose centroid lies
        within their segment's longest edge of it (a triangle touching the paint always does).
        A bounding-box test first, so the exact test only sees the triangles near the paint."""
        tris = []
        x0, y0, x1, y1 = paint.bounds
        for i in segment_ids:
            m = self.merged[i]
            cen, reach = self._segment_index(int(i))
            box = np.flatnonzero((cen[:, 0] >= x0 - reach) & (cen[:, 0] <= x1 + reach)
                                 & (cen[:, 1] >= y0 - reach) & (cen[:, 1] <= y1 + reach))
            if not len(box):
                continue
            zone = shapely.buffer(paint, reach, quad_segs=2)
            shapely.prepare(zone)
            sel = box[shapely.contains_xy(zone, cen[box, 0], cen[box, 1])]
            tris.append(m.vertices[m.faces[sel]])
        return RoadPatch(np.concatenate(tris) if tris else np.zeros((0, 3, 3)))


class RoadPatch:
    """Merged road triangles (T,3,3) with an STRtree over their XY bounding boxes."""

    def __init__(self, tris: np.ndarray) -> None:
        self.tris = tris
        lo, hi = tris[:, :, :2].min(axis=1), tris[:, :, :2].max(axis=1)
        self.tree = shapely.STRtree(shapely.box(lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]))

    def edges_in(self, poly: Polygon) -> np.ndarray:
        """The road's triangle edges clipped to ``poly``, as (K,2,2) segments."""
        idx = np.sort(self.tree.query(poly, predicate="intersects"))
        if not len(idx):
            return np.zeros((0, 2, 2))
        xy = self.tris[idx][:, :, :2]
        edges = np.concatenate([xy[:, [0, 1]], xy[:, [1, 2]], xy[:, [2, 0]]])
        # One copy of each shared edge (its two triangles list it in opposite directions).
        flip = (edges[:, 0, 0] > edges[:, 1, 0]) | ((edges[:, 0, 0] == edges[:, 1, 0]) & (edges[:, 0, 1] > edges[:, 1, 1]))
        edges[flip] = edges[flip][:, ::-1]
        edges = _unique_rows(edges.reshape(-1, 4)).reshape(-1, 2, 2)
        pieces = shapely.intersection(shapely.linestrings(edges), poly)
        segs = []
        for g in pieces[~shapely.is_empty(pieces)]:
            for line in getattr(g, "geoms", [g]):
                if line.geom_type == "LineString" and line.length > 1e-6:
                    c = np.asarray(line.coords)[:, :2]
                    segs.append(np.stack([c[:-1], c[1:]], axis=1))
        return np.concatenate(segs) if segs else np.zeros((0, 2, 2))

    def heights(self, xy: np.ndarray) -> np.ndarray:
        """Road surface z under each point: the first triangle a vertical ray hits, then
        barycentric interpolation; a point no triangle covers (float noise on the outline) takes
        the nearest triangle vertex's height. Points are bucketed in cells; each cell's candidate
        triangles come from one vectorised STRtree query, and all points are tested at once."""
        xy = np.asarray(xy, dtype=np.float64)
        z = np.full(len(xy), np.nan)
        if not len(xy):
            return z
        if not len(self.tris):
            raise RoadtwinError("lane marking lies off the road (no road surface under it)")
        cells = np.floor(xy / _CELL_M).astype(np.int64)
        _, inverse = np.unique(cells, axis=0, return_inverse=True)
        inverse = inverse.ravel()
        n_cells = int(inverse.max()) + 1
        lo = np.full((n_cells, 2), np.inf)
        hi = np.full((n_cells, 2), -np.inf)
        np.minimum.at(lo, inverse, xy)
        np.maximum.at(hi, inverse, xy)
        boxes = shapely.box(lo[:, 0] - 1e-9, lo[:, 1] - 1e-9, hi[:, 0] + 1e-9, hi[:, 1] + 1e-9)
        cell_of, tri_of = self.tree.query(boxes)
        # Every (point, candidate triangle of its cell) pair in one batch; the first hit in
        # triangle order is the one a per-cell pass finds (candidates sorted by index there too).
        n_cand = np.bincount(cell_of, minlength=n_cells)
        first_cand = np.cumsum(n_cand) - n_cand
        tri_sorted = tri_of[np.argsort(cell_of, kind="stable")]
        reps = n_cand[inverse]
        pair_p = np.repeat(np.arange(len(xy)), reps)
        pair_t = tri_sorted[np.repeat(first_cand[inverse], reps) + np.arange(len(pair_p))
                            - np.repeat(np.cumsum(reps) - reps, reps)]
        z = _heights_on(xy, self.tris, pair_p, pair_t)
        missing = np.isnan(z)
        if missing.any():
            pts = self.tris.reshape(-1, 3)
            _, j = cKDTree(pts[:, :2]).query(xy[missing])
            z[missing] = pts[j, 2]
        return z


def _unique_rows(rows: np.ndarray) -> np.ndarray:
    """``np.unique(rows, axis=0)`` for float rows from one lexsort (``np.unique`` on rows sorts a
    structured view, several times slower). Rows with a zero go to ``np.unique``: it treats
    -0.0 and 0.0 as equal and which one it keeps is its own affair."""
    if not len(rows) or (rows == 0).any():
        return np.unique(rows, axis=0)
    s = rows[np.lexsort(rows.T[::-1])]
    keep = np.r_[True, (s[1:] != s[:-1]).any(axis=1)]
    return s[keep]


def _heights_on(xy: np.ndarray, tri: np.ndarray, pair_p: np.ndarray, pair_t: np.ndarray) -> np.ndarray:
    """z under each point from its candidate (point, triangle) pairs: the lowest-index triangle
    a vertical ray hits, barycentric in it; NaN where none is hit."""
    hit = vertical_ray_hits_pairs(xy, tri, pair_p, pair_t, top=max(float(tri[..., 2].max()), 0.0) + 1.0)
    first = np.full(len(xy), len(tri), dtype=np.int64)
    np.minimum.at(first, pair_p[hit], pair_t[hit])
    first[first == len(tri)] = -1
    found = first >= 0
    z = np.full(len(xy), np.nan)
    t = tri[first[found]]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    e1, e2, r = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2], xy[found] - a[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    u = (r[:, 0] * e2[:, 1] - r[:, 1] * e2[:, 0]) / det
    v = (e1[:, 0] * r[:, 1] - e1[:, 1] * r[:, 0]) / det
    z[found] = (1 - u - v) * a[:, 2] + u * b[:, 2] + v * c[:, 2]
    return z


def _pslg(poly: Polygon, spacing_m: float, inner: np.ndarray) -> dict:
    """Triangle input for one paint polygon: its outline (points <= spacing apart) and the road
    edges inside, noded together by GEOS snap-rounding on a ``_GRID_M`` grid, so no two input
    segments cross and no two points nearly coincide (Triangle fails on both)."""
    lines = [shapely.segmentize(poly, spacing_m).boundary]
    if len(inner):
        lines.append(shapely.multilinestrings(shapely.linestrings(inner)))
    noded = shapely.union_all(lines, grid_size=_GRID_M)
    coords, part = shapely.get_coordinates(shapely.get_parts(noded), return_index=True)
    pts, inv = np.unique(coords, axis=0, return_inverse=True)
    inv = inv.ravel()
    same = part[:-1] == part[1:]
    segs = np.unique(np.sort(np.column_stack([inv[:-1][same], inv[1:][same]]), axis=1), axis=0)
    data = {"vertices": pts, "segments": segs[segs[:, 0] != segs[:, 1]]}
    holes = [Polygon(r).representative_point().coords[0] for r in poly.interiors]
    if holes:
        data["holes"] = np.asarray(holes)
    return data


def triangulate_paint(geom, spacing_m: float = SPACING_M, surface: RoadPatch | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Triangle CDT of (multi)polygons, boundary points <= spacing apart, interior triangles no
    larger than an equilateral of that side, the ``surface``'s road edges inside as constraints;
    (N,2) vertices and (M,3) counter-clockwise faces."""
    verts, faces, n = [], [], 0
    polys = [geom] if isinstance(geom, Polygon) else list(getattr(geom, "geoms", []))
    flags = f"pa{spacing_m ** 2 * np.sqrt(3) / 4:.6f}"
    for poly in polys:
        if not isinstance(poly, Polygon) or poly.area < _MIN_AREA_M2:
            continue
        inner = surface.edges_in(poly) if surface is not None else np.zeros((0, 2, 2))
        try:
            out = triangle.triangulate(_pslg(poly, spacing_m, inner), flags)
        except RuntimeError:
            # Last resort for a degenerate overlay: the outline alone (the paint then follows
            # the road at its vertices only, see the module docstring).
            out = triangle.triangulate(_pslg(poly, spacing_m, np.zeros((0, 2, 2))), flags)
        if "triangles" not in out or not len(out["triangles"]):
            continue
        # Keep only vertices a triangle uses (Triangle keeps input points it merged as duplicates).
        used, tris = np.unique(out["triangles"], return_inverse=True)
        verts.append(out["vertices"][used])
        faces.append(tris.reshape(-1, 3) + n)
        n += len(used)
    if not verts:
        return np.zeros((0, 2)), np.zeros((0, 3), dtype=np.int64)
    v, f = np.concatenate(verts), np.concatenate(faces).astype(np.int64)
    a = (v[f[:, 1]] - v[f[:, 0]])
    b = (v[f[:, 2]] - v[f[:, 0]])
    flip = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0] < 0
    f[flip] = f[flip][:, ::-1]
    return v, f


def build_markings(markings: list[LaneMarking], segments: list[RoadSegment], merged: list[MergedSegment],
                   placements: list[Placement], *, lift_m: float = LIFT_M, cut_margin_m: float = CUT_MARGIN_M,
                   spacing_m: float = SPACING_M, executor=None) -> list[MarkingMesh]:
    """Draped paint meshes, one per marking that keeps any paint (curbs and fully cut ones
    are left out), in the order of ``markings``.

    Which markings are drawn (a repeated line is drawn once) is decided here in order; cutting,
    triangulating and draping each one is independent of the others, so an ``executor``
    (:mod:`roadtwin_core.executors`) spreads that over the cores; results come back in order,
    so the meshes do not depend on it."""
    if not markings:
        return []
    surface = RoadSurface(segments, merged)
    holes = [Polygon(p.world_footprint()).buffer(cut_margin_m) for p in placements]
    hole_tree = shapely.STRtree(holes) if holes else None
    work = []
    painted: list = []                     # (colour, paint) of the markings kept so far
    for m in markings:
        pieces = line_paint(m)
        if not pieces:
            continue
        paint = shapely.union_all(pieces)  # dashes stay apart; the lines of a double marking may touch
        if _repeats(paint, m.color, painted):
            continue
        painted.append((m.color, paint))
        near = np.sort(hole_tree.query(paint)) if hole_tree is not None else []
        work.append((m, paint, [holes[i] for i in near]))
    context = (surface, lift_m, spacing_m)
    if executor is None:
        meshes = [_drape_marking(context, item) for item in work]
    else:
        meshes = executor.map(_drape_marking, context, work)
    return [mesh for mesh in meshes if mesh is not None]


def _drape_marking(context, item) -> MarkingMesh | None:
    """One marking's paint minus the defect holes near it, clipped, triangulated and draped
    (module-level so process pools can ship it)."""
    surface, lift_m, spacing_m = context
    m, paint, near_holes = item
    if near_holes:
        paint = paint.difference(shapely.union_all(near_holes))
    segment_ids = surface.near(paint)
    if not len(segment_ids):
        return None
    paint = paint.intersection(surface.outline(segment_ids))
    patch = surface.patch(segment_ids, paint)
    xy, faces = triangulate_paint(paint, spacing_m, patch)
    if not len(faces):
        return None
    z = patch.heights(xy) + lift_m
    return MarkingMesh(m.id, m.marking_type, m.color, np.column_stack([xy, z]), faces)


def _repeats(paint, color: str, painted: list, share: float = 0.5) -> bool:
    """True when more than ``share`` of this paint lies on paint of the same colour already
    drawn: a map that lists one line twice (CARLA's junction connecting roads come in pairs on
    one reference line) would otherwise get two coincident meshes that flicker in every viewer."""
    lo = np.asarray(paint.bounds)
    for c, other in painted:
        if c != color:
            continue
        b = np.asarray(other.bounds)
        if b[0] > lo[2] or b[2] < lo[0] or b[1] > lo[3] or b[3] < lo[1]:
            continue
        if paint.intersection(other).area > share * paint.area:
            return True
    return False


__all__ = ["MarkingMesh", "RoadPatch", "RoadSurface", "build_markings", "dash_intervals", "line_paint", "triangulate_paint",
           "LIFT_M", "CUT_MARGIN_M", "SPACING_M"]
