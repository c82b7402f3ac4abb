"""Export a composed town's road surface along a lane centerline as an OpenCRG file.

``export(stage_path, out_path)``:

1. The lane: the layout copied beside the composed stage (``<outdir>/layout/*.usda``, read with
   :func:`roadtwin_core.usd.read_layout`). Driving segments with a centerline are chained where one
   ends within 1 cm of where the next starts (same travel direction); the chain with the longest
   total centerline is taken (ties: layout order). Its centerlines, joined, are the reference line.
2. The grid: u every ``du`` = 5 cm along the resampled centerline; v every ``dv`` = 5 cm across
   the lane, symmetric, out to the half width of the chain's narrowest segment (twice the
   distance from its centerline's middle to its outline along the normal) rounded down to
   whole ``dv``.
   The reference line written is the one the CRG itself describes: phi per interval = heading of
   the resampled centerline chord, integrated from the first point (so :class:`CrgSurface` maps
   the written grid back to exactly the world points that were sampled).
3. Heights: vertical rays at each grid point's world xy against the stage's collision mesh (road
   with the defects baked in; :meth:`TownScene.collision_mesh`), by
   :class:`roadtwin_core.geometry.MeshHeights`: the topmost hit wins. Heights are absolute world
   z (reference line z = 0, no slope channel); a point no triangle covers is a missing (NaN) cell. On a curved
   lane that happens at the first and last cross section: the CRG's normal there is the
   first/last chord's, while the segment's end edge is radial, so half the section lies a few
   centimetres outside the mesh.
4. Written as binary ``KRBI`` (float32; about 4x smaller than LDFI), atomically.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from shapely.geometry import LineString, Point

from roadtwin_core import RoadtwinError
from roadtwin_core.geometry import MeshHeights
from roadtwin_core.usd import load_town, read_layout

from .crg import CRG, MAX_VALUES, CrgSurface, write_crg

DU = 0.05
DV = 0.05
JOIN_TOL = 0.01


def lane_chain(layout) -> list:
    """The longest chain of driving segments (with centerlines) joined end to start."""
    segs = [s for s in layout.segments if s.kind == "driving" and s.centerline is not None and len(s.centerline) >= 2]
    if not segs:
        raise RoadtwinError(f"{layout.source}: no driving segment with a centerline to export")

    def length(s) -> float:
        return float(np.linalg.norm(np.diff(s.centerline, axis=0), axis=1).sum())

    starts = np.array([s.centerline[0] for s in segs])
    nxt: dict[int, int] = {}
    has_prev: set[int] = set()
    for i, s in enumerate(segs):
        d = np.linalg.norm(starts - s.centerline[-1], axis=1)
        d[i] = np.inf
        j = int(np.argmin(d))
        if d[j] <= JOIN_TOL and j not in has_prev:
            nxt[i] = j
            has_prev.add(j)
    best: list[int] = []
    best_len = -1.0
    heads = [i for i in range(len(segs)) if i not in has_prev] or list(range(len(segs)))
    for h in heads:
        chain, seen, i = [], set(), h
        while i is not None and i not in seen:
            chain.append(i)
            seen.add(i)
            i = nxt.get(i)
        total = sum(length(segs[k]) for k in chain)
        if total > best_len + 1e-9:
            best, best_len = chain, total
    return [segs[k] for k in best]


def _resample(line: np.ndarray, du: float) -> np.ndarray:
    seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    line = line[keep]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
    n = int(math.floor(s[-1] / du + 1e-9)) + 1
    if n < 2:
        raise RoadtwinError("lane centerline is shorter than one CRG increment")
    q = np.arange(n) * du
    return np.column_stack([np.interp(q, s, line[:, 0]), np.interp(q, s, line[:, 1])])


def drape(vertices: np.ndarray, faces: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Topmost z of the mesh under each xy (vertical ray casting); NaN where nothing is hit."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(faces) == 0 or len(xy) == 0:
        return np.full(len(xy), np.nan)
    return MeshHeights(vertices, faces)(xy)


def _half_width(seg) -> float:
    """Distance from the middle of the centerline to the outline along the normal, both sides, min."""
    cl = seg.centerline
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(cl, axis=0), axis=1))])
    h = s[-1] / 2
    mid = np.array([np.interp(h, s, cl[:, 0]), np.interp(h, s, cl[:, 1])])
    k = min(max(int(np.searchsorted(s, h)), 1), len(cl) - 1)
    d = cl[k] - cl[k - 1]
    n = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-12)
    boundary = seg.polygon().boundary
    best = np.inf
    for sign in (1.0, -1.0):
        hit = boundary.intersection(LineString([mid, mid + sign * 100.0 * n]))
        if not hit.is_empty:
            best = min(best, hit.distance(Point(*mid)))
    return float(best)


def lane_crg(stage_path: str | Path, du: float = DU, dv: float = DV) -> CRG:
    """Sample the composed road surface of ``stage_path`` along the longest driving lane."""
    stage_path = Path(stage_path)
    if not stage_path.is_file():
        raise RoadtwinError(f"{stage_path}: " + ("is a directory, not a stage file" if stage_path.is_dir() else "no such file"))
    # before opening the stage: its sublayers name the layout, and USD would print its own warning
    layouts = sorted((stage_path.parent / "layout").glob("*.usda"))
    if not layouts:
        raise RoadtwinError(f"{stage_path}: no layout/*.usda beside the stage (export a stage written by roadtwin compose)")
    town = load_town(stage_path)
    layout = read_layout(layouts[0])
    chain = lane_chain(layout)
    line = np.concatenate([s.centerline if k == 0 else s.centerline[1:] for k, s in enumerate(chain)])
    half = min(_half_width(s) for s in chain)
    nvh = int(math.floor(half / dv + 1e-9))
    if nvh < 1:
        raise RoadtwinError(f"{stage_path}: lane {chain[0].id} is narrower than 2 x {dv} m")
    v = np.arange(-nvh, nvh + 1) * dv
    rows = float(np.linalg.norm(np.diff(line, axis=0), axis=1).sum()) / du + 1
    if rows * len(v) > MAX_VALUES:
        raise RoadtwinError(f"{stage_path}: lane {chain[0].id}: a {du} m x {dv} m grid of {rows:.4g} x {len(v)} values "
                            f"is too large for one CRG (limit {MAX_VALUES:,})")
    pts = _resample(line, du)
    phi_seg = np.arctan2(np.diff(pts[:, 1]), np.diff(pts[:, 0]))
    u = np.arange(len(pts)) * du
    phi = np.concatenate([[np.nan], phi_seg])
    comments = [f"roadtwin lane surface of {stage_path.name}",
                f"lane: {' -> '.join(s.id for s in chain)}",
                "heights: absolute world z (m) of the collision mesh; reference line z = 0"]
    crg = CRG.from_grid(u, v, np.zeros((len(u), len(v))), x0=float(pts[0, 0]), y0=float(pts[0, 1]),
                        phi0=float(phi_seg[0]), phi=phi, comments=comments)
    crg.road["reference_line_end_phi"] = float(phi_seg[-1])
    surf = CrgSurface(crg, warn=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    world = surf.world(uu.ravel(), vv.ravel())
    verts, faces = town.collision_mesh()
    crg.z = drape(verts, faces, world).reshape(len(u), len(v))
    if np.isnan(crg.z).all():
        raise RoadtwinError(f"{stage_path}: the collision mesh does not cover lane {chain[0].id}")
    return crg


class CrgExporter:
    name = "crg"
    suffix = ".crg"
    description = "road surface along the longest driving lane as an ASAM OpenCRG file (KRBI, 5 cm grid)"

    def export(self, stage_path, out_path) -> Path:
        out_path = Path(out_path)
        crg = lane_crg(stage_path)
        return write_crg(out_path, crg, binary=True)
