"""Even re-meshing of a planar road segment, shared by every merger.

Layout meshes (CARLA, OpenDRIVE strips) are long thin triangles; elevation restored only at
their vertices would lose the road's roughness, and a cut into them would be ragged. The outline
(non-convex, with holes) is kept exactly; each outline edge is split at points computed from its
endpoints in canonical order (:func:`roadtwin_core.geometry.subdivide_ring`), so two segments
sharing an edge get bit-identical border vertices and stay watertight.
"""
from __future__ import annotations

import math

import numpy as np
import shapely
import triangle
from shapely.geometry import Polygon

from .errors import RoadtwinError
from .geometry import polygon_loops, subdivide_ring
from .model import DefectModel, RoadSegment

__all__ = ["even_segment_mesh", "coarsen_defect"]


def even_segment_mesh(segment: RoadSegment, edge_m: float, rims: list[tuple[np.ndarray, np.ndarray]] = ()
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (N,2), faces (M,3), border_edges (E,2)): a quality triangulation, edges ~ ``edge_m``.

    ``rims`` — ``(points (K,2), edges (E,2) into points)`` — are inserted as extra constraint
    edges without Steiner points on them (a merger that wants the road to have a vertex at every
    defect rim vertex). Outline vertices come first, in outline order.
    """
    pts, segs, holes, offset = [], [], [], 0
    for k, loop in enumerate(polygon_loops(segment.polygon())):
        ring_pts = subdivide_ring(loop, edge_m)
        n = len(ring_pts)
        pts.append(ring_pts)
        segs.append(np.column_stack([np.arange(n), (np.arange(n) + 1) % n]) + offset)
        offset += n
        if k > 0:
            rp = Polygon(loop).representative_point()
            holes.append((rp.x, rp.y))
    border_edges = np.concatenate(segs)
    for rim_pts, rim_edges in rims:
        pts.append(np.asarray(rim_pts, dtype=np.float64).reshape(-1, 2))
        segs.append(np.asarray(rim_edges, dtype=np.int64).reshape(-1, 2) + offset)
        offset += len(pts[-1])
    verts = np.concatenate(pts)
    tri_in = {"vertices": verts, "segments": np.concatenate(segs)}
    if holes:
        tri_in["holes"] = np.array(holes)
    max_area = edge_m * edge_m * math.sqrt(3) / 4 * 1.5
    out = triangle.triangulate(tri_in, f"pq{25 if len(rims) else 30}YYa{max_area:.10f}")
    v = out["vertices"]
    if len(v) < len(verts) or not np.array_equal(v[: len(verts)], verts):
        what = "outline or defect rims" if len(rims) else "outline"
        raise RoadtwinError(f"road segment {segment.id!r}: {what} have duplicate or crossing vertices")
    return v, out["triangles"].astype(np.int64), border_edges


LOD_TOLERANCE_PER_EDGE = 0.004   # tolerance of a coarsened defect: 2 mm on a 0.5 m road mesh ...
LOD_MAX_TOLERANCE_M = 0.002      # ... and never coarser (faithful at 1 cm between vertices, tested)
_LOD_ROUNDS = 40


def coarsen_defect(model, edge_m: float, tol_m: float | None = None, volume_rtol: float = 0.005):
    """The defect model with as few vertices as keep it faithful to the road it goes into.

    Why: parametric generators sample a defect finely everywhere (up to ~1,800 triangles, loops of
    180 points ~1 cm apart), the bulk of a town's triangles, while the road around them has
    ``edge_m`` (0.5 m) edges. Level of detail here is error-driven, so it is faithful by
    construction: every vertex of the full model stays within ``tol_m`` (default
    ``LOD_TOLERANCE_PER_EDGE * edge_m``, at most ``LOD_MAX_TOLERANCE_M``: 2 mm) vertically *and* horizontally (loop) of the
    coarse surface. The boundary loop keeps an ordered subset of its vertices (Douglas-Peucker,
    never more than ``edge_m / 4`` apart, so the ring between road and defect stays small); the
    inside starts from the deepest and highest vertices and adds, round by round, the
    worst-fitting full-model vertex of every coarse triangle that misses the tolerance (greedy
    insertion, as in terrain simplification), re-triangulated with Triangle (no new points). The
    deepest and highest points are kept, so depth and height are exact.

    A piecewise-linear fit within ``tol_m`` can still bias the volume of a shallow, wide defect
    (a convex bowl is cut by every chord): when the volume moves by more than ``volume_rtol``, the
    tolerance is halved and the fit redone (at most 4 times, then the full model is kept).
    Models with pseudo-height vertices off the boundary (reconstructed ones) come back unchanged.
    """
    if model.pseudo_height is not None and int(model.pseudo_height.sum()) != len(model.boundary):
        return model
    tol = float(tol_m if tol_m is not None else min(LOD_TOLERANCE_PER_EDGE * edge_m, LOD_MAX_TOLERANCE_M))
    for _ in range(5):
        coarse = _coarsen(model, edge_m, tol)
        if coarse is None:
            return model
        if abs(coarse.signed_volume_m3 - model.signed_volume_m3) <= max(volume_rtol * model.volume_m3, 1e-9):
            return coarse
        tol /= 2.0
    return model


def locate_linear(vertices: np.ndarray, tris: np.ndarray, xy: np.ndarray):
    """Per query point ``xy`` (P, 2): the index of a triangle of ``(vertices, tris)`` holding it in
    XY (-1 outside all; on a shared edge, the lowest index) and ``vertices``' z linearly
    interpolated there (0 outside). Candidates from an STR-tree of the triangles' bounding boxes
    (shapely/GEOS), then barycentric coordinates of each (point, candidate) pair."""
    a, b, c = (vertices[tris[:, k]] for k in range(3))
    lo = np.minimum(np.minimum(a[:, :2], b[:, :2]), c[:, :2])
    hi = np.maximum(np.maximum(a[:, :2], b[:, :2]), c[:, :2])
    tree = shapely.STRtree(shapely.box(lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]))
    q, t = tree.query(shapely.points(xy), predicate="intersects")
    e1, e2 = b[t, :2] - a[t, :2], c[t, :2] - a[t, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    dx, dy = xy[q, 0] - a[t, 0], xy[q, 1] - a[t, 1]
    l1 = (dx * e2[:, 1] - dy * e2[:, 0]) / det
    l2 = (e1[:, 0] * dy - e1[:, 1] * dx) / det
    eps = -1e-9
    inside = (l1 >= eps) & (l2 >= eps) & (1.0 - l1 - l2 >= eps)
    q, t, l1, l2 = q[inside], t[inside], l1[inside], l2[inside]
    order = np.lexsort((t, q))                      # per point, its lowest triangle first
    q, t, l1, l2 = q[order], t[order], l1[order], l2[order]
    first = np.r_[True, q[1:] != q[:-1]]
    q, t, l1, l2 = q[first], t[first], l1[first], l2[first]
    owner = np.full(len(xy), -1, dtype=np.int64)
    z = np.zeros(len(xy))
    owner[q] = t
    z[q] = (1.0 - l1 - l2) * a[t, 2] + l1 * b[t, 2] + l2 * c[t, 2]
    return owner, z


def _coarsen(model, edge_m: float, tol: float):
    """One error-driven fit (see :func:`coarsen_defect`); None when it cannot be done."""
    v, loop = model.vertices, np.asarray(model.boundary)
    # Loop: Douglas-Peucker subset, then put back vertices where a gap exceeds edge_m / 4.
    ring = np.vstack([v[loop, :2], v[loop[:1], :2]])
    simple = np.asarray(shapely.simplify(shapely.linestrings(ring), tol, preserve_topology=True).coords)[:-1]
    index = {tuple(p): k for k, p in enumerate(v[loop, :2].tolist())}
    keep_loop = sorted({index[tuple(p)] for p in simple.tolist()} | {0})
    out = []
    gap = edge_m / 4.0
    loop_xy = v[loop, :2]
    for a, b in zip(keep_loop, keep_loop[1:] + [keep_loop[0] + len(loop)]):
        out.append(a)
        if b - a < 2:
            continue                         # adjacent kept vertices: nothing to put back
        span = np.arange(a, b + 1) % len(loop)
        step = np.linalg.norm(np.diff(loop_xy[span], axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(step)])
        span = span[:-1]
        last = 0.0
        for j in range(1, len(span)):        # keep a vertex wherever skipping it would open a gap
            if s[j + 1] - last > gap:
                out.append(int(span[j]))
                last = s[j]
    keep_loop = np.array(sorted(set(out)), dtype=np.int64)
    if len(keep_loop) < 3:
        return None
    coarse_loop = loop[keep_loop]
    # Checked: every full-model vertex but the kept loop, including the dropped loop vertices
    # (z = 0: where the loop is concave they lie inside the coarse footprint, over the dip).
    interior = np.setdiff1d(np.arange(len(v)), coarse_loop)
    if not len(np.setdiff1d(interior, loop)):
        return None
    inner = np.setdiff1d(interior, loop)
    chosen = list(dict.fromkeys([int(inner[np.argmin(v[inner, 2])]), int(inner[np.argmax(v[inner, 2])])]))
    n = len(coarse_loop)
    segs = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
    for _ in range(_LOD_ROUNDS):
        ids = np.concatenate([coarse_loop, chosen])
        out_t = triangle.triangulate({"vertices": v[ids, :2], "segments": segs}, "pYYQ")
        if len(out_t["vertices"]) != len(ids):
            return None                      # Triangle had to add points: keep the full model
        tris = out_t["triangles"].astype(np.int64)
        owner, z = locate_linear(v[ids], tris, v[interior, :2])
        err = np.abs(np.where(owner >= 0, z, 0.0) - v[interior, 2])   # outside the coarse loop: the road plane
        bad = err > tol
        bad[np.isin(interior, chosen)] = False
        if not bad.any():
            break
        cand = np.flatnonzero(bad)
        order = cand[np.lexsort((-err[cand], owner[cand]))]       # per triangle, worst first
        first = np.r_[True, owner[order][1:] != owner[order][:-1]]
        chosen.extend(int(i) for i in interior[order[first]])
    else:
        return None
    ids = np.concatenate([coarse_loop, chosen])
    return DefectModel(name=model.name, defect_type=model.defect_type, vertices=v[ids].copy(), faces=tris,
                       boundary=np.arange(n), source=model.source, params=dict(model.params), look=model.look)
