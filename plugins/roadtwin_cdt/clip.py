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
from shapely.geometry import Polygon

from roadtwin_core import Placement, RoadtwinError, polygon_area
from roadtwin_core.geometry import boundary_edges, loops_from_edges, vertical_ray_hits


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
    remap = {int(v): n + i for i, v in enumerate(bverts)}
    pts = np.concatenate([w[:, :2], v2[bverts]])
    dedges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    bsegs = np.array([[remap[int(i)], remap[int(j)]] for i, j in bedges], dtype=np.int64).reshape(-1, 2)
    out = triangle.triangulate({"vertices": pts, "segments": np.concatenate([dedges, bsegs])}, "p")
    ov, ot = out["vertices"], out["triangles"].astype(np.int64)
    if not np.array_equal(ov[: len(pts)], pts):
        raise RoadtwinError(f"{what}: defect vertices coincide with the segment border; move the defect")
    cen = ov[ot].mean(axis=1)
    keep = shapely.contains_xy(footprint, cen[:, 0], cen[:, 1]) & shapely.contains_xy(segment_poly, cen[:, 0], cen[:, 1])
    ot = ot[keep]
    if len(ot) == 0:
        return None
    rel = np.zeros(len(ov))
    rel[:n] = w[:, 2]
    new = np.arange(n, len(ov))
    if len(new):
        rel[new] = _interpolate(w, faces, ov[new])
    used, inverse = np.unique(ot, return_inverse=True)
    vertices = np.column_stack([ov[used], rel[used]])
    pf = inverse.reshape(-1, 3).astype(np.int64)
    loops = loops_from_edges(boundary_edges(pf))
    seeds = _seeds(vertices, pf, loops)
    return DefectPiece(vertices, pf, loops, footprint.intersection(segment_poly), seeds[0], seeds[1:])


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
    hits = vertical_ray_hits(xy, tri[near])
    found = hits.any(axis=1)
    f = faces[near[hits.argmax(axis=1)[found]]]
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
