"""Closed solids for the boolean merger, as plain numpy arrays, and their manifold3d conversion.

Every solid here is a *sheet extrusion*: a 2.5D triangulated disk (or polygon with holes)
given top and bottom heights per vertex, closed by vertical walls along its boundary edges.
The triangle order is fixed — ``[top faces | bottom faces | walls]`` — and each triangle's
manifold ``face_id`` is its index, so after a boolean every output triangle says which input
triangle it was cut from (top, bottom or wall of which solid).
"""
from __future__ import annotations

import manifold3d
import numpy as np
import triangle
from shapely.geometry import Polygon

from roadtwin_core import RoadSegment, RoadtwinError, polygon_area
from roadtwin_core.geometry import boundary_edges, loops_from_edges  # boundary_edges: re-exported for merger.py
from roadtwin_core.remesh import even_segment_mesh as _core_even_mesh


def even_segment_mesh(segment: RoadSegment, edge_m: float,
                      rims: list[tuple[np.ndarray, np.ndarray]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N,2), faces (M,3)): roadtwin_core's even re-mesh, with the defect ``rims``
    built in as constraint edges, so the road top has the exact surface height the defect rim has
    and the boolean leaves no step along the rim on a curved surface."""
    v, f, _ = _core_even_mesh(segment, edge_m, rims)
    return v, f


def outline_mesh(xy: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A Steiner-free triangulation of a sheet's outline (holes kept) using only its boundary
    vertices, as faces into ``xy``: the cheapest cap with exactly the sheet's boundary edges,
    for solids whose flat top or bottom needs none of the sheet's interior vertices."""
    edges = boundary_edges(faces)
    ids = np.unique(edges)
    local = np.full(int(faces.max()) + 1, -1, dtype=np.int64)
    local[ids] = np.arange(len(ids))
    tri_in = {"vertices": xy[ids], "segments": local[edges]}
    # Hole seeds: Triangle eats triangles from the convex hull inwards up to segments ('p'), but
    # interior holes need a seed; one point inside each clockwise (hole) loop's region.
    holes = _hole_seeds(xy, faces, edges)
    if holes:
        tri_in["holes"] = np.array(holes)
    out = triangle.triangulate(tri_in, "pYY")
    if len(out["vertices"]) != len(ids):
        raise RoadtwinError("outline triangulation added vertices (self-touching outline)")
    return ids[out["triangles"].astype(np.int64)]


def _hole_seeds(xy: np.ndarray, faces: np.ndarray, edges: np.ndarray) -> list[tuple[float, float]]:
    seeds = []
    for loop in loops_from_edges(edges):
        if polygon_area(xy[loop]) < 0:  # a hole loop runs clockwise around the sheet's hole
            rp = Polygon(xy[loop]).representative_point()
            seeds.append((rp.x, rp.y))
    return seeds


def extrude_sheet(xy: np.ndarray, faces: np.ndarray, z_top: np.ndarray, z_bottom: np.ndarray,
                  top_faces: np.ndarray | None = None, bottom_faces: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Closed solid between two heights over one sheet: (vertices, triangles, n_top, n_bottom).

    ``faces`` must be counter-clockwise seen from +Z and use every vertex. ``top_faces`` /
    ``bottom_faces`` (default ``faces``) may replace one side by a cap with the same boundary
    edges (``outline_mesh``), e.g. where that side is flat. Triangles come as
    ``[top (n_top) | bottom (n_bottom) | walls (2 per boundary edge)]``; walls stand on the
    directed boundary edges, so the solid is outward-oriented for outer loops and holes alike.
    Unused vertices are dropped.
    """
    n = len(xy)
    top = faces if top_faces is None else top_faces
    bottom = faces if bottom_faces is None else bottom_faces
    z_top = np.broadcast_to(np.asarray(z_top, dtype=np.float64), (n,))
    z_bottom = np.broadcast_to(np.asarray(z_bottom, dtype=np.float64), (n,))
    if not (z_top > z_bottom).all():
        raise RoadtwinError("solid top must lie above its bottom everywhere (thickness too small?)")
    verts = np.concatenate([np.column_stack([xy, z_top]), np.column_stack([xy, z_bottom])])
    e = boundary_edges(faces)
    a, b = e[:, 0], e[:, 1]
    walls = np.concatenate([np.column_stack([a, a + n, b + n]), np.column_stack([a, b + n, b])])
    tris = np.concatenate([top, bottom[:, ::-1] + n, walls]).astype(np.int64)
    if top_faces is not None or bottom_faces is not None:
        used, inverse = np.unique(tris, return_inverse=True)
        verts, tris = verts[used], inverse.reshape(-1, 3).astype(np.int64)
    return verts, tris, len(top), len(bottom)


def compact(xy_or_v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop unused vertices: (vertices, faces, kept vertex ids)."""
    used, inverse = np.unique(faces, return_inverse=True)
    return xy_or_v[used], inverse.reshape(-1, 3).astype(np.int64), used


def to_manifold(verts: np.ndarray, tris: np.ndarray, original_id: int, tolerance: float, what: str):
    """A manifold3d.Manifold in double precision whose triangles remember where they came from:
    ``face_id`` = input triangle index, one run with the given (reserved) ``originalID``.
    Refuses anything that is not a closed oriented 2-manifold."""
    mesh = manifold3d.Mesh64(vert_properties=np.ascontiguousarray(verts, dtype=np.float64),
                             tri_verts=np.ascontiguousarray(tris, dtype=np.uint64),
                             face_id=np.arange(len(tris), dtype=np.uint64),
                             run_original_id=np.array([original_id], dtype=np.uint32),
                             run_index=np.array([0, 3 * len(tris)], dtype=np.uint64),
                             tolerance=float(tolerance))
    solid = manifold3d.Manifold(mesh)
    status = solid.status()
    if status != manifold3d.Error.NoError or solid.is_empty():
        raise RoadtwinError(f"{what}: is not a closed oriented 2-manifold ({status})")
    return solid


__all__ = ["even_segment_mesh", "outline_mesh", "extrude_sheet", "compact", "to_manifold", "boundary_edges"]
