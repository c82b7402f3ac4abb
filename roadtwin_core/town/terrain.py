"""The terrain mesh under a town's props: ground out to the horizon that never comes up inside
the road.

The terrain lies ``below_m`` under the surface model (its coarse grid interpolates the surface,
so it must sit a little lower to stay hidden by the road where both exist). Under the paved
surface it must not exist at all: a pothole, depression or rut deeper than ``below_m`` would show
it through its floor. So the grid's triangles are clipped against the *cut*: the paved surface
shrunk by ``overlap_m`` (the terrain reaches that far under the road edge, so no camera sees a
gap between the road and the ground beside it) plus each defect's disc where it lies on the paved
surface (a deep defect at the road edge sees no terrain either). Triangles wholly outside the cut
are kept as they are, those wholly inside dropped, and the rest replaced by a constrained
Delaunay triangulation of what lies outside the cut (shapely, GEOS).
"""
from __future__ import annotations

import numpy as np
import shapely

from .prop_shapes import ground_grid


def terrain_cut(paved, discs: np.ndarray, overlap_m: float):
    """Where the terrain must not be: ``paved`` shrunk by ``overlap_m``, plus the (N,3) discs
    (x, y, radius) clipped to ``paved``."""
    cut = paved.buffer(-overlap_m, quad_segs=4)
    discs = np.asarray(discs, np.float64).reshape(-1, 3)
    if len(discs):
        # 16-gons drawn around the circles (not inside them): each disc is wholly in the cut
        circles = shapely.buffer(shapely.points(discs[:, :2]), discs[:, 2] / np.cos(np.pi / 16), quad_segs=4)
        shapely.prepare(cut)
        edge = circles[~shapely.contains_properly(cut, circles)]     # most defects lie well inside
        if len(edge):
            cut = shapely.union_all([cut, shapely.intersection(shapely.union_all(edge), paved)])
    return cut


def _grid(bounds, cell_m: float, pad_m: float, apron_m: float):
    x0, y0, x1, y1 = bounds
    xs, ys = ground_grid((x0 - pad_m, y0 - pad_m, x1 + pad_m, y1 + pad_m), cell_m, apron_m)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    nx = len(xs)
    i, j = np.meshgrid(np.arange(len(ys) - 1), np.arange(nx - 1), indexing="ij")
    a = (i * nx + j).ravel()
    faces = np.concatenate([np.column_stack([a, a + 1, a + nx + 1]), np.column_stack([a, a + nx + 1, a + nx])])
    return xy, faces


def _clipped(tri_xy: np.ndarray, cut) -> np.ndarray:
    """(M,3,2) triangles covering the parts of the (K,3,2) triangles outside ``cut``."""
    outside = shapely.difference(shapely.polygons(tri_xy), cut)
    pieces = shapely.get_parts(shapely.get_parts(shapely.constrained_delaunay_triangles(outside)))
    pieces = pieces[~shapely.is_empty(pieces) & (shapely.area(pieces) > 1e-8)]
    if not len(pieces):
        return np.zeros((0, 3, 2))
    ring = shapely.get_coordinates(shapely.get_exterior_ring(pieces)).reshape(len(pieces), 4, 2)
    return ring[:, :3]


def terrain_mesh(paved, height, discs: np.ndarray = (), cell_m: float = 10.0, pad_m: float = 40.0,
                 apron_m: float = 700.0, below_m: float = 0.08, overlap_m: float = 0.5):
    """Terrain (vertices (V,3), faces (F,3) int64) on a grid ``cell_m`` apart over ``paved``'s
    bounds + ``pad_m``, coarser out to ``apron_m``, ``below_m`` under ``height(xy)``, with
    nothing inside :func:`terrain_cut`. Counter-clockwise from above (normals up)."""
    cut = terrain_cut(paved, discs, overlap_m)
    shapely.prepare(cut)
    xy, faces = _grid(paved.bounds, cell_m, pad_m, apron_m)
    tris = shapely.polygons(xy[faces])
    hit = np.zeros(len(faces), bool)
    hit[shapely.STRtree(tris).query(cut, predicate="intersects")] = True
    inside = np.zeros(len(faces), bool)
    inside[hit] = shapely.within(tris[hit], cut)
    kept = faces[~hit]
    new = _clipped(xy[faces[hit & ~inside]], cut)
    # the clipped triangles' corners join the grid's (same corner, same vertex: a watertight mesh)
    all_xy = np.concatenate([xy[kept].reshape(-1, 2), new.reshape(-1, 2)])
    key = np.round(all_xy * 1000.0).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    v = all_xy[first]
    f = inv.reshape(-1, 3).astype(np.int64)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    # GEOS may wind either way: make every face counter-clockwise seen from above
    e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    f[cw] = f[cw][:, ::-1]
    return np.column_stack([v, height(v) - below_m]), f
