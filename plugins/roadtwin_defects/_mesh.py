"""Shared recipe: (footprint loop, height function) -> DefectModel.

Why one helper: every parametric type is the same three steps. A simple CCW footprint loop
becomes the boundary *exactly* (Triangle flag ``Y``: no Steiner points on segments, so the merger
gets the loop it was promised, in order, as vertices ``0..n-1``); the inside is a constrained
Delaunay triangulation; z comes from the type's height function while the loop keeps z = 0.
Types differ only in their footprint, their height function and a few interior points or
constraint lines placed where the surface bends (rim rings, crack centrelines), which lets a
small mesh (hundreds to ~2000 triangles) still follow the shape.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Iterable

import numpy as np
import shapely
import triangle
from shapely.geometry import Polygon
from shapely.validation import explain_validity

from roadtwin_core import DefectModel, RoadtwinError, polygon_area

HeightFn = Callable[[np.ndarray], np.ndarray]

_DEDUP_M = 1e-6  # interior points closer than this are one point


def loop_spacing(perimeter_m: float, lo: float = 0.01, hi: float = 0.08, points: int = 240) -> float:
    """Boundary spacing: ~``points`` loop vertices, but never finer than lo nor coarser than hi."""
    return float(np.clip(perimeter_m / points, lo, hi))


def closed_length(points: np.ndarray) -> float:
    p = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())


def resample_closed(points: np.ndarray, spacing: float, phase: float = 0.0) -> np.ndarray:
    """Uniform arc-length resampling of a densely sampled closed curve (no repeated end point).

    ``phase`` (0..1) shifts the samples by a fraction of a step, e.g. to stagger nested rings.
    """
    p = np.asarray(points, dtype=np.float64)
    closed = np.vstack([p, p[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    n = max(8, int(round(s[-1] / spacing)))
    t = (np.arange(n) + phase) * s[-1] / n
    return np.column_stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])])


def densify_closed(loop: np.ndarray, max_spacing: float) -> np.ndarray:
    """Keep every vertex and split longer edges evenly: same shape, so a simple loop stays simple."""
    p = np.asarray(loop, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    out = []
    for a, b in zip(p, q):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / max_spacing)))
        t = np.arange(k)[:, None] / k
        out.append(a + t * (b - a))
    return np.vstack(out)


def densify_open(points: np.ndarray, max_spacing: float) -> np.ndarray:
    """Keep every vertex of an open polyline and split longer edges evenly."""
    p = np.asarray(points, dtype=np.float64)
    return np.vstack([densify_closed(p, max_spacing)[: -_last_edge_count(p, max_spacing)], p[-1:]])


def _last_edge_count(p: np.ndarray, max_spacing: float) -> int:
    """Points densify_closed puts on the closing edge p[-1] -> p[0] (dropped for open lines)."""
    return max(1, int(np.ceil(np.linalg.norm(p[0] - p[-1]) / max_spacing)))


def build_defect(*, name: str, defect_type: str, params: Any, loop: np.ndarray, height: HeightFn,
                 extra_points: np.ndarray | None = None,
                 extra_lines: Iterable[tuple[np.ndarray, bool]] = (),
                 max_area: float | None = None, min_angle: float | None = 28.0,
                 margin: float = 1e-4, stretch: float = 1.0) -> DefectModel:
    """Triangulate ``loop`` (+ interior points/constraint lines) and lift it with ``height``.

    ``extra_points`` are free interior points (dropped if outside or within ``margin`` of the
    loop). ``extra_lines`` are interior polylines ``(points, closed)`` kept as triangle edges; they
    must lie strictly inside. ``height(xy) -> z`` is evaluated on interior vertices only; the loop
    is the pseudo-height boundary at z = 0. ``stretch`` > 1 triangulates with x divided by it
    and maps back: quality triangles there are triangles elongated along x here, the right
    shape for surfaces that vary slowly along x (ruts). A positive axis scale keeps orientation,
    simplicity and the loop order, and ``max_area`` is then measured in the stretched frame.
    """
    owner = f"defect type {defect_type}"
    loop = np.asarray(loop, dtype=np.float64)
    if polygon_area(loop) < 0:
        loop = loop[::-1].copy()
    poly = Polygon(loop)
    if not poly.is_valid or len(poly.interiors):
        raise RoadtwinError(f"{owner}: footprint is not a simple polygon ({explain_validity(poly)})")
    n = len(loop)
    seg = [np.column_stack([np.arange(n), (np.arange(n) + 1) % n])]

    # Constraint lines first (they must all survive), then free points.
    pts: list[np.ndarray] = []
    line_idx: list[tuple[int, int, bool]] = []
    count = 0
    for line, closed in extra_lines:
        line = np.asarray(line, dtype=np.float64).reshape(-1, 2)
        pts.append(line)
        line_idx.append((count, len(line), closed))
        count += len(line)
    n_line = count
    if extra_points is not None and len(extra_points):
        pts.append(np.asarray(extra_points, dtype=np.float64).reshape(-1, 2))
    inner = np.vstack(pts) if pts else np.zeros((0, 2))
    if len(inner):
        inside = shapely.contains_xy(poly, inner[:, 0], inner[:, 1])
        inside &= shapely.distance(poly.exterior, shapely.points(inner)) > margin
        if not inside[:n_line].all():
            raise RoadtwinError(f"{owner}: an interior line leaves the footprint (internal error)")
        keep = inside.copy()
        # Deduplicate (keeping first occurrences, so line points win) and map line indices.
        key = np.round(inner / _DEDUP_M).astype(np.int64)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        canonical = first[inverse]
        keep &= canonical == np.arange(len(inner))
        new_index = np.cumsum(keep) - 1
        for start, k, closed in line_idx:
            ids = new_index[canonical[start:start + k]] + n
            a, b = (ids, np.roll(ids, -1)) if closed else (ids[:-1], ids[1:])
            pair = np.column_stack([a, b])
            seg.append(pair[pair[:, 0] != pair[:, 1]])
        inner = inner[keep]
    opts = "pY"
    if min_angle:
        opts += f"q{min_angle:g}"
    if max_area:
        opts += f"a{max_area:.12f}"
    scale = np.array([stretch, 1.0])
    out = triangle.triangulate({"vertices": np.vstack([loop, inner]) / scale, "segments": np.vstack(seg)}, opts)
    v2 = out["vertices"] * scale
    faces = np.asarray(out["triangles"], dtype=np.int64)
    if len(v2) < n or not np.allclose(v2[:n], loop, rtol=0, atol=1e-12):
        raise RoadtwinError(f"{owner}: triangulation moved the boundary loop (internal error)")
    v2[:n] = loop  # bit-exact loop after the round trip through the stretch
    # Compact unused vertices while keeping the loop first and in order.
    used = np.zeros(len(v2), dtype=bool)
    used[faces.ravel()] = True
    used[:n] = True
    remap = np.cumsum(used) - 1
    v2, faces = v2[used], remap[faces]
    z = np.zeros(len(v2))
    z[n:] = np.asarray(height(v2[n:]), dtype=np.float64)
    if not np.isfinite(z).all():
        raise RoadtwinError(f"{owner}: height function gave NaN/inf (internal error)")
    return DefectModel(name=name, defect_type=defect_type, vertices=np.column_stack([v2, z]),
                       faces=faces, boundary=np.arange(n), source="parametric",
                       params=dataclasses.asdict(params))


def cosine_bell(u: np.ndarray) -> np.ndarray:
    """1 at u = 0, 0 with zero slope at u >= 1: a smooth (C1) bump profile."""
    u = np.clip(u, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))
