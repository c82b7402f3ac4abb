"""A crack label's strokes on the road -> one simple polygon to mesh (core-free: numpy, scipy, shapely).

Why: real crack labels are thin strokes (median 2A/P 2.55 px at 512x320), and a rendered
defect is labelled over its whole mesh, so a crack asset's mesh must be the strokes, not the
area they span (closing the strokes and filling the outline labelled road between them as crack:
5.87 px, twice the real width; issue 22). A defect model has ONE boundary loop and no holes
(docs/architecture.md, "Library assets"; the merger cuts the road along it), and it is placed as
one piece, so a crack network's strokes become one simple polygon:

1. the footprint texels as polygons at texel edges (row runs unioned: the area is exactly the
   texel count, holes kept), closed by half a texel (diagonal touches and one-texel notches);
2. parts (strokes the instance grouped, ``join_px``) joined by bridges ``gap_m`` wide along the
   shortest links between them (a minimum spanning tree over the parts' nearest points);
3. each hole (road enclosed by strokes) larger than ``fill_m2`` opened to the outside by a slit
   ``gap_m`` wide where the strokes around it are thinnest; smaller holes are filled (label
   noise, not road).

The result's area is the strokes' plus bridges minus slits: a few percent at most.

A stroke mesh covers one to three texels across, so a renderer's MIP levels (box-filtered) and
bilinear taps mix a stroke's texels with those beside it. :func:`pad_from_footprint` gives every
texel outside the strokes the value of the nearest stroke texel (edge padding, the dilation
texture bakers use against MIP bleeding): whatever level is sampled on the mesh sees only stroke
colour, not the road colour of the fade band (which made the strokes vanish at survey range).
The colour padded from is the strokes' dark core (:func:`stroke_core`): a photo's crack label
is wider than the crack (an annotator's stroke, pooled to the label's size), and the renderer's
class map grows rendered crack labels by the same margin again (``dilate_px``), so a mesh
painted with the label's mean colour would count the light rim twice.
"""
from __future__ import annotations

import numpy as np
import shapely
from scipy.ndimage import distance_transform_edt, minimum_filter
from scipy.sparse.csgraph import minimum_spanning_tree
from shapely.geometry import LineString, MultiPolygon, Polygon, box
from shapely.ops import nearest_points

from .rectify import OrthoGrid


def texel_polygons(foot: np.ndarray, grid: OrthoGrid):
    """The True texels of ``foot`` as a (multi)polygon in road xy, at texel edges."""
    t = grid.texel
    boxes = []
    padded = np.pad(foot.astype(np.int8), ((0, 0), (1, 1)))
    for r in np.flatnonzero(foot.any(axis=1)):
        d = np.diff(padded[r])
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)     # cols [start, end)
        x_hi, x_lo = grid.x_max - r * t, grid.x_max - (r + 1) * t
        boxes += [box(x_lo, grid.y_max - e * t, x_hi, grid.y_max - s * t) for s, e in zip(starts, ends)]
    return shapely.union_all(boxes) if boxes else Polygon()


def _parts(geom) -> list[Polygon]:
    if geom.is_empty:
        return []
    return list(geom.geoms) if isinstance(geom, MultiPolygon) else [geom]


def bridge_parts(geom, width: float):
    """Parts joined by ``width``-wide bridges along a minimum spanning tree of their distances."""
    parts = _parts(geom)
    if len(parts) < 2:
        return geom
    n = len(parts)
    dist = np.zeros((n, n))
    for i in range(n):
        dist[i, i + 1:] = shapely.distance(parts[i], parts[i + 1:])
    tree = minimum_spanning_tree(np.where(dist > 0, dist, 1e-12) * np.triu(np.ones((n, n)), 1)).tocoo()
    bridges = []
    for i, j in zip(tree.row, tree.col):
        a, b = nearest_points(parts[i], parts[j])
        link = LineString([a, b]) if a.distance(b) > 0 else a
        bridges.append(link.buffer(width / 2, cap_style="square", join_style="mitre"))
    return shapely.union_all([geom, *bridges])


def open_hole(poly: Polygon, hole, width: float):
    """``poly`` less a ``width``-wide slit from ``hole`` to the outside, across the thinnest stroke."""
    a, b = nearest_points(hole, poly.exterior)
    d = np.subtract(b.coords[0], a.coords[0])
    if float(np.hypot(*d)) < 1e-9:                 # the hole touches the outside at a point: open it there
        return poly.difference(a.buffer(width / 2, cap_style="square"))
    d = d / float(np.hypot(*d))
    p0 = np.asarray(a.coords[0]) - d * width
    p1 = np.asarray(b.coords[0]) + d * width
    return poly.difference(LineString([p0, p1]).buffer(width / 2, cap_style="flat", join_style="mitre"))


def stroke_outline(foot: np.ndarray, grid: OrthoGrid, gap_m: float, fill_m2: float) -> Polygon | None:
    """One simple polygon (no holes) over the strokes of ``foot``; None when none is reached."""
    t = grid.texel
    geom = texel_polygons(foot, grid)
    if geom.is_empty:
        return None
    close = t / 2
    # texel squares that touch at a corner meet in zero-length edges, where GEOS's mitre offset
    # raises a floating-point flag that shapely reports as numpy's RuntimeWarning on every crack
    # of a `reconstruct photos` run; the outline below is checked valid before it is used
    with np.errstate(divide="ignore", invalid="ignore"):
        geom = geom.buffer(close, join_style="mitre").buffer(-close, join_style="mitre")
    width = max(gap_m, t)
    for _ in range(64):
        geom = geom.buffer(0)
        parts = _parts(geom)
        if not parts:
            return None
        if len(parts) > 1:
            geom = bridge_parts(geom, width)
            continue
        poly = parts[0]
        small = [h for h in poly.interiors if Polygon(h).area <= fill_m2]
        if small:
            geom = shapely.union_all([poly, *(Polygon(h).buffer(t / 4) for h in small)])
            continue
        if poly.interiors:
            geom = open_hole(poly, max(poly.interiors, key=lambda h: Polygon(h).area), width)
            continue
        poly = poly.simplify(t / 2, preserve_topology=True)
        if isinstance(poly, Polygon) and poly.is_valid and not poly.interiors and poly.area > 0:
            return poly
        return None
    return None


def ccw_ring(poly) -> np.ndarray:
    """The polygon's outer ring (no repeated end point), counter-clockwise."""
    ring = np.asarray(poly.exterior.coords)[:-1]
    a = 0.5 * np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    return ring if a > 0 else ring[::-1].copy()


def min_face_area(xy: np.ndarray, faces: np.ndarray) -> float:
    """The smallest triangle's XY area once the points are float32 (as a USD asset stores them)."""
    q = xy[:, :2].astype(np.float32).astype(np.float64)[faces]
    cross = (q[:, 1, 0] - q[:, 0, 0]) * (q[:, 2, 1] - q[:, 0, 1]) - (q[:, 1, 1] - q[:, 0, 1]) * (q[:, 2, 0] - q[:, 0, 0])
    return float(0.5 * cross.min()) if len(q) else 0.0


def pad_from_footprint(image: np.ndarray, foot: np.ndarray) -> np.ndarray:
    """``image`` (R, C[, K]) with every texel outside ``foot`` (R, C) set to its nearest footprint
    texel's value (Euclidean; ties by scipy's scan order, so the same input gives the same bytes).
    Inside ``foot`` nothing changes; an empty footprint returns the image unchanged."""
    if not foot.any() or foot.all():
        return image
    _, (rows, cols) = distance_transform_edt(~foot, return_indices=True)
    return image[rows, cols]


def stroke_core(lum: np.ndarray, foot: np.ndarray, radius: int) -> np.ndarray:
    """The footprint texels that are the darkest (``lum``) of the footprint within ``radius``
    texels (a square window): the crack itself inside its wider label."""
    if radius <= 0:
        return foot
    darkest = minimum_filter(np.where(foot, lum, np.inf), size=2 * radius + 1, mode="nearest")
    return foot & (lum <= darkest)
