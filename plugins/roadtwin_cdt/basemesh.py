"""Re-mesh a planar road segment to an even triangle size before merging.

Layout meshes (CARLA, OpenDRIVE strips) are long thin triangles; elevation restored only at
their vertices would lose the road's roughness, and a ring cut into them would be ragged. The
outline (non-convex, with holes) is kept exactly; each outline edge is split at points computed
from its endpoints in canonical order, so neighbouring segments that share an edge get the same
border vertices and stay watertight.
"""
from __future__ import annotations

import math

import numpy as np
import triangle
from shapely.geometry import Polygon

from roadtwin_core import RoadSegment, RoadtwinError
from roadtwin_core.geometry import polygon_loops, subdivide_edge


def segment_base_mesh(segment: RoadSegment, edge_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (N,2), faces (M,3), border_edges (E,2)) of a quality triangulation of the segment."""
    pts: list[np.ndarray] = []
    segs: list[np.ndarray] = []
    holes: list[tuple[float, float]] = []
    offset = 0
    for k, loop in enumerate(polygon_loops(segment.polygon())):
        ring = []
        for i in range(len(loop)):
            a, b = loop[i], loop[(i + 1) % len(loop)]
            ring.append(a[None])
            ring.append(subdivide_edge(a, b, edge_m))
        ring_pts = np.concatenate(ring)
        n = len(ring_pts)
        pts.append(ring_pts)
        segs.append(np.column_stack([np.arange(n), (np.arange(n) + 1) % n]) + offset)
        offset += n
        if k > 0:
            rp = Polygon(loop).representative_point()
            holes.append((rp.x, rp.y))
    verts = np.concatenate(pts)
    border_edges = np.concatenate(segs)
    tri_in = {"vertices": verts, "segments": border_edges}
    if holes:
        tri_in["holes"] = np.array(holes)
    max_area = edge_m * edge_m * math.sqrt(3) / 4 * 1.5
    out = triangle.triangulate(tri_in, f"pq30YYa{max_area:.10f}")
    v = out["vertices"]
    if len(v) < len(verts) or not np.array_equal(v[: len(verts)], verts):
        raise RoadtwinError(f"road segment {segment.id!r}: outline has duplicate or crossing vertices")
    return v, out["triangles"].astype(np.int64), border_edges
