"""Reference routes: drivable distance, the shortest drivable path (the paper's reference
"road midline"), and each cell's offset and heading relative to it."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from ..errors import RoadtwinError
from .grid import GridMap


def drivable_distance(grid: GridMap, xy: Sequence[float], mask: np.ndarray | None = None,
                      predecessors: bool = False):
    """8-connected shortest distance (m) over ``mask`` (default: drivable) from the cell of ``xy``
    to every cell (+inf where unreachable); with ``predecessors`` also the predecessor array."""
    mask = grid.drivable if mask is None else mask
    ny, nx = mask.shape
    ix, iy = grid.world_to_cell(np.asarray(xy, dtype=np.float64)[:2])
    dist = np.full(mask.shape, np.inf)
    pred = np.full(mask.shape, -1, np.int64)
    if not (grid.inside(ix, iy) and mask[iy, ix]):
        return (dist, pred) if predecessors else dist
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(int(mask.sum()))
    rows, cols, w = [], [], []
    r = grid.resolution
    for dy, dx, cost in ((0, 1, r), (1, 0, r), (1, 1, r * math.sqrt(2)), (1, -1, r * math.sqrt(2))):
        y0, y1 = max(0, -dy), ny - max(0, dy)
        x0, x1 = max(0, -dx), nx - max(0, dx)
        a = index[y0:y1, x0:x1]
        b = index[y0 + dy:y1 + dy, x0 + dx:x1 + dx]
        ok = (a >= 0) & (b >= 0)
        rows.append(a[ok])
        cols.append(b[ok])
        w.append(np.full(int(ok.sum()), cost))
    n = int(mask.sum())
    graph = csr_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    d, p = dijkstra(graph, directed=False, indices=int(index[iy, ix]), return_predecessors=True)
    dist[mask] = d
    if predecessors:
        cells = np.flatnonzero(mask.ravel())
        pred[mask] = np.where(p >= 0, cells[np.maximum(p, 0)], -1)
        return dist, pred
    return dist


def segment_drivable(grid: GridMap, a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether the straight segment a-b stays on drivable cells (sampled every quarter cell)."""
    a, b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / (grid.resolution / 4))) + 1)
    pts = a + np.linspace(0, 1, n)[:, None] * (b - a)
    return bool(grid.sample(grid.drivable, pts, False).all())


def reference_path(grid: GridMap, start: Sequence[float], goal: Sequence[float]) -> np.ndarray:
    """The paper's reference ("the road midline"): the shortest drivable path start -> goal,
    defects ignored. The straight line when it stays on the lanes; otherwise the 8-connected
    geodesic, string-pulled (greedy line of sight) so it is not 8% too long on diagonals."""
    a, b = np.asarray(start, float)[:2], np.asarray(goal, float)[:2]
    if segment_drivable(grid, a, b):
        return np.array([a, b])
    dist, pred = drivable_distance(grid, a, predecessors=True)
    gx, gy = grid.world_to_cell(b)
    if not (grid.inside(gx, gy) and np.isfinite(dist[gy, gx])):
        raise RoadtwinError("goal is unreachable: no drivable connection from the start")
    ny, nx = grid.shape
    cells = [int(gy * nx + gx)]
    flat_pred = pred.ravel()
    while flat_pred[cells[-1]] >= 0:
        cells.append(int(flat_pred[cells[-1]]))
    cells = cells[::-1]
    pts = grid.cell_to_world(np.array(cells) % nx, np.array(cells) // nx)
    pts = np.concatenate([[a], pts[1:-1], [b]]) if len(pts) > 2 else np.array([a, b])
    out = [pts[0]]
    i = 0
    while i < len(pts) - 1:
        j = i + 1
        while j + 1 < len(pts) and segment_drivable(grid, pts[i], pts[j + 1]):
            j += 1
        out.append(pts[j])
        i = j
    return np.array(out)


def reference_frame(grid: GridMap, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per drivable cell, the distance (m) to a reference polyline (the route's midline) and the
    direction (rad) of its nearest segment; NaN elsewhere."""
    ref = np.asarray(reference, dtype=np.float64)[:, :2]
    dist = np.full(grid.shape, np.nan)
    head = np.full(grid.shape, np.nan)
    if len(ref) < 2:
        return dist, head
    a, seg = ref[:-1], np.diff(ref, axis=0)
    length2 = np.maximum((seg ** 2).sum(axis=1), 1e-12)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    iy, ix = np.nonzero(grid.drivable)
    pts = grid.cell_to_world(ix, iy)
    best = np.full(len(pts), np.inf)
    which = np.zeros(len(pts), np.int64)
    for k in range(len(seg)):
        t = np.clip(((pts - a[k]) @ seg[k]) / length2[k], 0.0, 1.0)
        d = ((a[k] + t[:, None] * seg[k] - pts) ** 2).sum(axis=1)
        closer = d < best
        best[closer] = d[closer]
        which[closer] = k
    dist[iy, ix] = np.sqrt(best)
    head[iy, ix] = heading[which]
    return dist, head


def lane_headings(grid: GridMap, reference: np.ndarray) -> np.ndarray:
    """Per drivable cell, the direction (rad) of the nearest segment of a reference polyline
    (the route's midline); NaN elsewhere. Grid planners keep the footprint at this heading."""
    return reference_frame(grid, reference)[1]


def polyline_length(xy: np.ndarray) -> float:
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0

