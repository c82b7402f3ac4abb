"""Planar mesh geometry shared by the core and plugins (numpy in, numpy out)."""
from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon

from .errors import RoadtwinError


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges used by exactly one face (the mesh outline, holes included)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    n = int(faces.max()) + 1 if len(faces) else 1
    key = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])  # 1D keys: ~10x faster
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return e[counts[inverse.reshape(-1)] == 1]


def edge_face_counts(faces: np.ndarray) -> np.ndarray:
    """How many faces use each undirected edge (2 inside a manifold surface, 1 on its border)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def mesh_outline_polygon(vertices: np.ndarray, faces: np.ndarray, what: str) -> Polygon:
    """Union of the mesh's triangles as one valid polygon; refuses degenerate/self-overlapping meshes."""
    tris = vertices[faces][:, :, :2]
    area2 = ((tris[:, 1, 0] - tris[:, 0, 0]) * (tris[:, 2, 1] - tris[:, 0, 1])
             - (tris[:, 1, 1] - tris[:, 0, 1]) * (tris[:, 2, 0] - tris[:, 0, 0]))
    if not (np.abs(area2) > 1e-12).all():
        raise RoadtwinError(f"{what}: has degenerate (zero-area) triangles")
    polys = shapely.polygons(tris)
    total = float(np.abs(area2).sum() / 2)
    # A mesh's triangles tile its outline (edge-to-edge, no overlaps), which is exactly the input
    # coverage_union_all is made for (~6x faster than union_all). It does not check that, so its
    # result is used only when it is one valid polygon of the triangles' total area; anything
    # else goes through union_all and the checks below name what is wrong.
    try:
        fast = shapely.coverage_union_all(polys)
    except shapely.errors.GEOSException:      # e.g. "incorrectly noded inputs": not a tiling
        fast = None
    if (fast is not None and fast.geom_type == "Polygon" and fast.is_valid
            and abs(fast.area - total) <= 1e-9 * max(total, 1.0)):
        return fast
    union = shapely.union_all(polys)
    if abs(union.area - total) > 1e-6 * max(total, 1.0):
        raise RoadtwinError(f"{what}: triangles overlap (self-intersecting segment)")
    if union.geom_type != "Polygon":
        raise RoadtwinError(f"{what}: is not one connected polygon")
    return union


def polygon_loops(poly: Polygon) -> list[np.ndarray]:
    """Exterior and interior rings of a polygon as (K,2) arrays without the closing point."""
    rings = [poly.exterior, *poly.interiors]
    return [np.asarray(r.coords)[:-1, :2] for r in rings]


def subdivide_edge(a: np.ndarray, b: np.ndarray, spacing: float) -> np.ndarray:
    """Points strictly between a and b, evenly spaced.

    Computed from the endpoints in a canonical (sorted) order so two segments sharing this
    edge get bit-identical points and stay watertight along their border.
    """
    n = int(np.ceil(np.hypot(*(b - a)) / spacing))
    if n <= 1:
        return np.zeros((0, 2))
    flip = (b[0], b[1]) < (a[0], a[1])
    p, q = (b, a) if flip else (a, b)
    t = np.arange(1, n) / n
    pts = p[None, :] + t[:, None] * (q - p)[None, :]
    return pts[::-1] if flip else pts


def subdivide_ring(loop: np.ndarray, spacing: float) -> np.ndarray:
    """A closed loop (K,2) with every edge subdivided: each vertex followed by
    :func:`subdivide_edge` of the edge it starts, the same points bit for bit.

    Why: an outline has thousands of edges; one vectorised pass replaces as many Python calls."""
    a = np.asarray(loop, dtype=np.float64)
    b = np.roll(a, -1, axis=0)
    d = b - a
    n = np.ceil(np.hypot(d[:, 0], d[:, 1]) / spacing).astype(np.int64)
    m = np.where(n > 1, n - 1, 0)                       # inner points per edge
    flip = (b[:, 0] < a[:, 0]) | ((b[:, 0] == a[:, 0]) & (b[:, 1] < a[:, 1]))
    p = np.where(flip[:, None], b, a)
    q = np.where(flip[:, None], a, b)
    edge = np.repeat(np.arange(len(a)), m)
    j = np.arange(len(edge)) - np.repeat(np.cumsum(m) - m, m)
    k = np.where(flip[edge], m[edge] - j, j + 1)        # flipped edges list their points reversed
    pts = p[edge] + (k / n[edge])[:, None] * (q - p)[edge]
    start = np.arange(len(a)) + np.cumsum(m) - m
    out = np.empty((len(a) + len(edge), 2))
    out[start] = a
    out[start[edge] + 1 + j] = pts
    return out


def vertical_ray_hits(origins_xy: np.ndarray, tri: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Möller–Trumbore for vertical rays: which triangles each downward ray hits.

    ``origins_xy`` (P,2) start far above the mesh and point along -Z; ``tri`` is (T,3,3).
    Returns a (P,T) boolean matrix. Vectorised over all pairs (callers chunk large inputs).
    """
    d = np.array([0.0, 0.0, -1.0])
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    pvec = np.cross(d, e2)  # (T,3)
    det = (e1 * pvec).sum(-1)  # (T,)
    ok = np.abs(det) > eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    top = max(float(tri[..., 2].max()), 0.0) + 1.0
    o = np.column_stack([origins_xy, np.full(len(origins_xy), top)])
    tvec = o[:, None, :] - v0[None]  # (P,T,3)
    u = (tvec * pvec[None]).sum(-1) * inv[None]
    qvec = np.cross(tvec, e1[None])
    v = (qvec * d).sum(-1) * inv[None]
    t = (qvec * e2[None]).sum(-1) * inv[None]
    tol = 1e-12
    return ok[None] & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t >= 0)


def vertical_ray_hits_pairs(origins_xy: np.ndarray, tri: np.ndarray, pair_origin: np.ndarray,
                            pair_tri: np.ndarray, top: float | None = None, eps: float = 1e-12) -> np.ndarray:
    """:func:`vertical_ray_hits` for chosen (ray, triangle) pairs only: one boolean per pair.

    Why: callers batch every defect of a segment into one call, and most rays are nowhere near
    most triangles. A pair whose ray misses the triangle's XY bounding box (grown by 1 um, far
    above the 1e-12 barycentric tolerance) cannot hit; the others run the same Möller–Trumbore
    arithmetic as :func:`vertical_ray_hits` element for element, so each answer is bit-identical.
    ``top`` is the rays' start height (default: as :func:`vertical_ray_hits` computes it from ``tri``).
    """
    out = np.zeros(len(pair_origin), dtype=bool)
    if not len(pair_origin):
        return out
    if top is None:
        top = max(float(tri[..., 2].max()), 0.0) + 1.0
    lo, hi = tri[:, :, :2].min(axis=1) - 1e-6, tri[:, :, :2].max(axis=1) + 1e-6
    o_xy, t_lo, t_hi = origins_xy[pair_origin], lo[pair_tri], hi[pair_tri]
    near = np.flatnonzero(((o_xy >= t_lo) & (o_xy <= t_hi)).all(axis=1))
    if not len(near):
        return out
    d = np.array([0.0, 0.0, -1.0])
    t3 = tri[pair_tri[near]]
    v0, v1, v2 = t3[:, 0], t3[:, 1], t3[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    pvec = np.cross(d, e2)
    det = (e1 * pvec).sum(-1)
    ok = np.abs(det) > eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    o = np.column_stack([o_xy[near], np.full(len(near), top)])
    tvec = o - v0
    u = (tvec * pvec).sum(-1) * inv
    qvec = np.cross(tvec, e1)
    v = (qvec * d).sum(-1) * inv
    t = (qvec * e2).sum(-1) * inv
    tol = 1e-12
    out[near] = ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t >= 0)
    return out


def first_vertical_hits(origins_xy: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Index of the first triangle (in ``tri`` order) each downward ray hits, -1 for none: what
    ``vertical_ray_hits(origins_xy, tri).argmax(axis=1)`` picks, with the (P, T) matrix replaced
    by :func:`vertical_ray_hits_pairs` (bit-identical tests, only near pairs evaluated)."""
    pair_p = np.repeat(np.arange(len(origins_xy)), len(tri))
    pair_t = np.tile(np.arange(len(tri)), len(origins_xy))
    hit = vertical_ray_hits_pairs(origins_xy, tri, pair_p, pair_t)
    first = np.full(len(origins_xy), len(tri), dtype=np.int64)
    np.minimum.at(first, pair_p[hit], pair_t[hit])
    return np.where(first < len(tri), first, -1)


class MeshHeights:
    """Height of the topmost triangle under XY points (NaN off the mesh): the one helper for
    "the surface under (x, y)" (cameras placed above the road, OpenCRG grids draped on it). A
    uniform grid over the triangles' XY bounding boxes (sorted cell keys, numpy only: about 40
    bytes a triangle, where a shapely STRtree of 1.8 M triangle polygons took 1.5 GB), then a
    barycentric inside test in XY (what a vertical ray's Möller–Trumbore test reduces to) and z.
    Triangles with no XY area (walls) are never under a point.

    ``cell_m`` is the grid pitch; by default the median triangle's XY extent (at least 5 cm),
    so a point meets a few candidates whatever the mesh's resolution."""

    CHUNK = 100_000            # point-triangle candidate pairs tested at once (their temporaries stay in cache)

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, cell_m: float | None = None):
        tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]
        area = 0.5 * np.abs((tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1])
                            - (tri[:, 1, 1] - tri[:, 0, 1]) * (tri[:, 2, 0] - tri[:, 0, 0]))
        tri = tri[area > 1e-12]
        self.coef = _barycentric_table(tri)
        lo, hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
        if cell_m is None:
            cell_m = max(float(np.median((hi - lo).max(axis=1))), 0.05) if len(lo) else 1.0
        self.cell = float(cell_m)
        self.origin = lo.min(axis=0) if len(lo) else np.zeros(2)
        c0 = np.floor((lo - self.origin) / self.cell).astype(np.int64)
        c1 = np.floor((hi - self.origin) / self.cell).astype(np.int64)
        self.ny = int(c1[:, 1].max()) + 2 if len(c1) else 1
        nx, ny = c1[:, 0] - c0[:, 0] + 1, c1[:, 1] - c0[:, 1] + 1
        count = nx * ny
        owner = np.repeat(np.arange(len(tri)), count)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
        keys = (c0[owner, 0] + k % nx[owner]) * self.ny + c0[owner, 1] + k // nx[owner]
        order = np.argsort(keys, kind="stable")
        self.keys, self.owner = keys[order], owner[order].astype(np.int64)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        out = np.full(len(xy), np.nan)
        if not len(xy) or not len(self.coef):
            return out
        c = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        ok = (c >= 0).all(axis=1) & (c[:, 1] < self.ny)
        q = np.where(ok, c[:, 0] * self.ny + c[:, 1], -1)
        first, last = np.searchsorted(self.keys, q, "left"), np.searchsorted(self.keys, q, "right")
        n = np.where(ok, last - first, 0)
        pi = np.repeat(np.arange(len(xy)), n)
        if not len(pi):
            return out
        ti = self.owner[np.repeat(first, n) + np.arange(len(pi)) - np.repeat(np.cumsum(n) - n, n)]
        for s in range(0, len(pi), self.CHUNK):
            self._top(xy, pi[s:s + self.CHUNK], ti[s:s + self.CHUNK], out)
        return out

    def _top(self, xy: np.ndarray, pi: np.ndarray, ti: np.ndarray, out: np.ndarray) -> None:
        k = self.coef[ti]
        p = xy[pi]
        v2x, v2y = p[:, 0] - k[:, 0], p[:, 1] - k[:, 1]
        beta = (v2x * k[:, 5] - k[:, 4] * v2y) / k[:, 6]
        gamma = (k[:, 2] * v2y - v2x * k[:, 3]) / k[:, 6]
        inside = np.nonzero((beta >= -1e-9) & (gamma >= -1e-9) & (beta + gamma <= 1 + 1e-9))[0]
        k = k[inside]
        np.fmax.at(out, pi[inside], k[:, 7] + beta[inside] * k[:, 8] + gamma[inside] * k[:, 9])


def _barycentric_table(tri: np.ndarray) -> np.ndarray:
    """Per triangle (T,3,3) what ``MeshHeights._top`` needs of it, computed once: the first
    vertex's XY, the two edge vectors from it (XY), their cross product, its z and the two edges'
    rise (T,10). The same operations as per point-triangle pair, so the heights are unchanged."""
    a = tri[:, 0]
    v0, v1 = tri[:, 1, :2] - a[:, :2], tri[:, 2, :2] - a[:, :2]
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    return np.column_stack([a[:, 0], a[:, 1], v0, v1, den, a[:, 2], tri[:, 1, 2] - a[:, 2], tri[:, 2, 2] - a[:, 2]])


def triangle_min_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smallest interior angle (degrees, in XY) of each triangle."""
    p = vertices[faces][:, :, :2]
    angles = []
    for i in range(3):
        a = p[:, (i + 1) % 3] - p[:, i]
        b = p[:, (i + 2) % 3] - p[:, i]
        cos = (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(angles, axis=0)


def loops_from_edges(edges: np.ndarray) -> list[np.ndarray]:
    """Chain directed boundary edges into closed vertex loops."""
    nxt = {int(a): int(b) for a, b in edges}
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt.get(v, start)
        loops.append(np.array(loop, dtype=np.int64))
    return loops


__all__ = ["boundary_edges", "edge_face_counts", "mesh_outline_polygon", "polygon_loops",
           "subdivide_edge", "subdivide_ring", "vertical_ray_hits",
           "vertical_ray_hits_pairs", "first_vertical_hits", "MeshHeights", "triangle_min_angles", "loops_from_edges"]
