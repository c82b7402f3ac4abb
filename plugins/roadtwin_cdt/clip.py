"""Defect pieces: a placed defect as the merger sees it, clipped to one segment if it straddles.

Clipping re-triangulates the defect mesh with the segment's border edges as extra constraints
(Triangle inserts the crossing points) and keeps the triangles inside both. New vertices get
their relative height by barycentric interpolation in the original defect triangle (found by a
vertical Möller–Trumbore ray), so the clipped surface is exactly the original one, cut.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
import triangle
from scipy.spatial import cKDTree
from shapely.geometry import Polygon

from roadtwin_core import Placement, RoadtwinError, polygon_area
from roadtwin_core.geometry import boundary_edges, first_vertical_hits, loops_from_edges


@dataclass
class DefectPiece:
    vertices: np.ndarray          # (k,3): world xy, z relative to the road surface
    faces: np.ndarray             # (m,3) into vertices
    loops: list[np.ndarray]       # boundary loops (indices into vertices), shared with the ring
    region: object                # shapely footprint of this piece
    seed: tuple[float, float]     # a point strictly inside (hole seed for the ring CDT)
    extra_seeds: list = field(default_factory=list)


def clip_defect(p: Placement, segment_poly, v2: np.ndarray, border_edges: np.ndarray, what: str) -> DefectPiece | None:
    w = p.world_vertices()
    faces = p.model.faces
    loop = p.model.boundary
    footprint = Polygon(w[loop, :2])
    if not footprint.is_valid:
        raise RoadtwinError(f"{what}: footprint is self-intersecting")
    if segment_poly.contains(footprint):
        seeds = _seeds(w, faces, [loop])
        return DefectPiece(w, faces, [loop], footprint, seeds[0], seeds[1:])
    return _clip(w, faces, footprint, segment_poly, v2, border_edges, what)


def _clip(w, faces, footprint, segment_poly, v2, border_edges, what) -> DefectPiece | None:
    x0, y0, x1, y1 = footprint.bounds
    a, b = v2[border_edges[:, 0]], v2[border_edges[:, 1]]
    near = ((np.maximum(a[:, 0], b[:, 0]) >= x0) & (np.minimum(a[:, 0], b[:, 0]) <= x1)
            & (np.maximum(a[:, 1], b[:, 1]) >= y0) & (np.minimum(a[:, 1], b[:, 1]) <= y1))
    bedges = border_edges[near]
    bverts = np.unique(bedges)
    n = len(w)
    remap = np.full(int(border_edges.max()) + 1, -1, dtype=np.int64)
    remap[bverts] = n + np.arange(len(bverts))
    pts = np.concatenate([w[:, :2], v2[bverts]])
    dedges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    segs, pts, zrel = _planar_graph(pts, w[:, 2], dedges, remap[bedges])
    # Every crossing is an explicit vertex now: Triangle never intersects segments itself (it
    # can crash on near-degenerate crossings, e.g. a rim vertex a rounding error off the border).
    out = triangle.triangulate({"vertices": pts, "segments": segs}, "pQ")
    ov, ot = out["vertices"], out["triangles"].astype(np.int64)
    if not np.array_equal(ov[: len(pts)], pts):
        raise RoadtwinError(f"{what}: defect vertices coincide with the segment border; move the defect")
    cen = ov[ot].mean(axis=1)
    keep = shapely.contains_xy(footprint, cen[:, 0], cen[:, 1]) & shapely.contains_xy(segment_poly, cen[:, 0], cen[:, 1])
    ot = ot[keep]
    if len(ot) == 0:
        return None
    rel = np.zeros(len(ov))
    rel[: len(zrel)] = zrel
    rel[:n] = w[:, 2]
    unknown = np.concatenate([np.flatnonzero(np.isnan(zrel)), np.arange(len(zrel), len(ov))])
    if len(unknown):
        rel[unknown] = _interpolate(w, faces, ov[unknown])
    used, inverse = np.unique(ot, return_inverse=True)
    vertices = np.column_stack([ov[used], rel[used]])
    pf = inverse.reshape(-1, 3).astype(np.int64)
    loops = loops_from_edges(boundary_edges(pf))
    seeds = _seeds(vertices, pf, loops)
    return DefectPiece(vertices, pf, loops, footprint.intersection(segment_poly), seeds[0], seeds[1:])


def _planar_graph(pts: np.ndarray, z: np.ndarray, dedges: np.ndarray, bedges: np.ndarray, eps: float = 1e-10):
    """Split defect edges and border edges at every point where they meet, so the segment set
    has no crossings. Crossing points are computed from the border edge taken in canonical
    (sorted-endpoint) order, so the neighbouring segment computes the same bits. Returns
    (segments, points, relative z per point: known for defect vertices and crossings, NaN for
    border vertices, which the caller interpolates)."""
    nd = len(z)
    zrel = np.concatenate([z, np.full(len(pts) - nd, np.nan)])
    # A border vertex on top of a defect vertex (e.g. a rim vertex exactly on a subdivision
    # point of the border) is that defect vertex: duplicates crash Triangle.
    dist, nearest = cKDTree(pts[:nd]).query(pts[nd:])
    alias = np.arange(len(pts))
    alias[nd:] = np.where(dist <= eps, nearest, alias[nd:])
    bedges = alias[bedges]
    bedges = bedges[bedges[:, 0] != bedges[:, 1]]
    a, b = pts[bedges[:, 0]], pts[bedges[:, 1]]
    flip = (b[:, 0] < a[:, 0]) | ((b[:, 0] == a[:, 0]) & (b[:, 1] < a[:, 1]))
    a, b = np.where(flip[:, None], b, a), np.where(flip[:, None], a, b)
    c, d = pts[dedges[:, 0]], pts[dedges[:, 1]]
    r, sv = b - a, d - c
    qp = c[None] - a[:, None]                                    # (E, D, 2)
    denom = r[:, None, 0] * sv[None, :, 1] - r[:, None, 1] * sv[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * sv[None, :, 1] - qp[..., 1] * sv[None, :, 0]) / denom
        u = (qp[..., 0] * r[:, None, 1] - qp[..., 1] * r[:, None, 0]) / denom
    lr = np.linalg.norm(r, axis=1)[:, None]
    ls = np.linalg.norm(sv, axis=1)[None, :]
    cross = (np.abs(denom) > 0) & (t * lr > eps) & ((1 - t) * lr > eps) & (u * ls > eps) & ((1 - u) * ls > eps)
    b_split: dict[int, list[tuple[float, int]]] = {}
    d_split: dict[int, list[tuple[float, int]]] = {}
    new_pts, new_z = [], []
    for i, j in zip(*np.nonzero(cross)):
        k = len(pts) + len(new_pts)
        new_pts.append(a[i] + t[i, j] * r[i])
        new_z.append(z[dedges[j, 0]] + u[i, j] * (z[dedges[j, 1]] - z[dedges[j, 0]]))
        b_split.setdefault(i, []).append((t[i, j], k))
        d_split.setdefault(j, []).append((u[i, j], k))
    # A vertex of one set lying on an edge of the other (within eps) splits that edge there.
    border_only = np.unique(bedges)
    border_only = border_only[border_only >= nd]
    for edges_a, verts, split, canon in ((bedges, np.arange(nd), b_split, True),
                                         (dedges, border_only, d_split, False)):
        p0, p1 = (a, b) if canon else (c, d)
        seg = p1 - p0
        L2 = (seg * seg).sum(1)
        q = pts[verts]
        tt = ((q[:, None] - p0[None]) * seg[None]).sum(-1) / L2[None]
        dist = np.linalg.norm(q[:, None] - (p0[None] + tt[..., None] * seg[None]), axis=-1)
        L = np.sqrt(L2)[None]
        on = (dist <= eps) & (tt * L > eps) & ((1 - tt) * L > eps)
        for vi, e in zip(*np.nonzero(on)):
            if verts[vi] not in edges_a[e]:
                split.setdefault(e, []).append((tt[vi, e], int(verts[vi])))
    if new_pts:
        pts = np.concatenate([pts, np.array(new_pts)])
        zrel = np.concatenate([zrel, np.array(new_z)])

    def chains(edges, split, canon_flip):
        """Each edge in order, a split one replaced by its chain (few are split: only those
        are walked in Python)."""
        count = np.ones(len(edges), dtype=np.int64)
        for e, points in split.items():
            count[e] += len(points)
        start = np.cumsum(count) - count
        out = np.empty((int(count.sum()), 2), dtype=np.int64)
        whole = count == 1
        out[start[whole]] = edges[whole]
        for e, points in split.items():
            mid = [k for _, k in sorted(points)]
            if canon_flip is not None and canon_flip[e]:
                mid = mid[::-1]  # params were taken from the canonical end
            ids = [int(edges[e, 0]), *mid, int(edges[e, 1])]
            out[start[e]:start[e] + len(ids) - 1] = np.column_stack([ids[:-1], ids[1:]])
        return out

    segs = np.concatenate([chains(dedges, d_split, None), chains(bedges, b_split, flip)])
    # Drop aliased (unused) points: Triangle crashes on duplicate input vertices even unused.
    # Defect vertices are all used by their own edges, so they keep their indices 0..nd-1.
    used = np.unique(segs)
    index = np.full(len(pts), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return index[segs], pts[used], zrel[used]


def _interpolate(w: np.ndarray, faces: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Relative height of the defect surface at xy (0 outside the footprint): a vertical
    Möller–Trumbore ray per point finds its defect face, then barycentric interpolation."""
    tri = w[faces].copy()
    tri[:, :, 2] = 0.0
    lo, hi = xy.min(axis=0) - 1e-9, xy.max(axis=0) + 1e-9
    near = np.flatnonzero((tri[:, :, 0].max(1) >= lo[0]) & (tri[:, :, 0].min(1) <= hi[0])
                          & (tri[:, :, 1].max(1) >= lo[1]) & (tri[:, :, 1].min(1) <= hi[1]))
    z = np.zeros(len(xy))
    if len(near) == 0:
        return z
    first = first_vertical_hits(xy, tri[near])
    found = first >= 0
    f = faces[near[first[found]]]
    pa, pb, pc = w[f[:, 0], :2], w[f[:, 1], :2], w[f[:, 2], :2]
    e1, e2, r = pb - pa, pc - pa, xy[found] - pa
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    u = (r[:, 0] * e2[:, 1] - r[:, 1] * e2[:, 0]) / det
    v = (e1[:, 0] * r[:, 1] - e1[:, 1] * r[:, 0]) / det
    z[found] = (1 - u - v) * w[f[:, 0], 2] + u * w[f[:, 1], 2] + v * w[f[:, 2], 2]
    return z


def _seeds(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray]) -> list[tuple[float, float]]:
    """One interior point per outer loop: the centroid of the face along its first edge."""
    seeds = []
    for loop in loops:
        if polygon_area(vertices[loop, :2]) <= 0:
            continue
        e0, e1 = loop[0], loop[1]
        has = ((faces == e0) & (np.roll(faces, -1, axis=1) == e1)).any(axis=1)
        f = faces[np.flatnonzero(has)[0]]
        c = vertices[f, :2].mean(axis=0)
        seeds.append((float(c[0]), float(c[1])))
    if not seeds:
        raise RoadtwinError("defect piece has no outer boundary loop")
    return seeds
