"""Even re-meshing of a planar road segment, shared by every merger.

Layout meshes (CARLA, OpenDRIVE strips) are long thin triangles; elevation restored only at
their vertices would lose the road's roughness, and a cut into them would be ragged. The outline
(non-convex, with holes) is kept exactly; each outline edge is split at points computed from its
endpoints in canonical order (:func:`roadtwin_core.geometry.subdivide_edge`), so two segments
sharing an edge get bit-identical border vertices and stay watertight.
"""
from __future__ import annotations

import math

import numpy as np
import triangle
from shapely.geometry import Polygon

from .errors import RoadtwinError
from .geometry import polygon_loops, subdivide_edge
from .model import RoadSegment


def even_segment_mesh(segment: RoadSegment, edge_m: float, rims: list[tuple[np.ndarray, np.ndarray]] = ()
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (N,2), faces (M,3), border_edges (E,2)): a quality triangulation, edges ~ ``edge_m``.

    ``rims`` — ``(points (K,2), edges (E,2) into points)`` — are inserted as extra constraint
    edges without Steiner points on them (a merger that wants the road to have a vertex at every
    defect rim vertex). Outline vertices come first, in outline order.
    """
    pts, segs, holes, offset = [], [], [], 0
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
