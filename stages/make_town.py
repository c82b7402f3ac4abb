"""Generate stages/town.usda, the sample town shipped with roadtwin.

A small street grid with six junctions and two-lane streets (3.5 m lanes, 2 m sidewalks), one
avenue bending through a 90-degree curve, segments split every 25 m like CARLA's, neighbouring segments
sharing their border vertices exactly. Terrain is a gentle synthetic hill sampled every 5 m
(the k-d tree elevation source). Lane markings, US-style like CARLA's towns: a broken yellow
centre line between the opposing lanes (0.125 m, CARLA Town01's width; 3 m dashes, 9 m gaps, the
MUTCD values the OpenDRIVE importer uses too) and solid white edge lines (0.12 m) on the
driving/sidewalk borders of every street, none inside junctions.
Run: ``python stages/make_town.py`` (output is deterministic).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import triangle

from roadtwin_core import ComposeRules, LaneMarking, RoadSegment, TownLayout
from roadtwin_core.usd import write_layout

LANE, WALK, SPLIT = 3.5, 2.0, 25.0
CENTRE_WIDTH, EDGE_WIDTH, DASH, GAP = 0.125, 0.12, 3.0, 9.0


def _mesh(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(poly)
    t = triangle.triangulate({"vertices": poly, "segments": np.column_stack([np.arange(n), (np.arange(n) + 1) % n])}, "p")
    return t["vertices"], t["triangles"]


def strip(center: np.ndarray, offsets: list[float], kinds: list[str], name: str) -> list[RoadSegment]:
    """Strips between consecutive lateral offsets along a centerline polyline, cut every SPLIT m."""
    normal = _normals(center)
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(center, axis=0), axis=1))])
    cuts = np.unique(np.concatenate([[0], np.searchsorted(s, np.arange(SPLIT, s[-1] - 1e-6, SPLIT)), [len(s) - 1]]))
    edges = [center + o * normal for o in offsets]
    segs = []
    for piece, (i0, i1) in enumerate(zip(cuts[:-1], cuts[1:])):
        for k, kind in enumerate(kinds):
            lo, hi = edges[k][i0:i1 + 1], edges[k + 1][i0:i1 + 1]
            poly = np.concatenate([lo, hi[::-1]])
            v, f = _mesh(poly)
            mid = 0.5 * (lo + hi)
            direction = mid if offsets[k] + offsets[k + 1] <= 0 else mid[::-1]  # right-hand traffic
            segs.append(RoadSegment(f"{name}_{piece:02d}_{k}", kind, v, f, direction if kind == "driving" else None,
                                    {"road": name}))
    return segs


def _normals(center: np.ndarray) -> np.ndarray:
    d = np.gradient(center, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.column_stack([-d[:, 1], d[:, 0]])


def markings(center: np.ndarray, name: str) -> list[LaneMarking]:
    """Centre line along the street's centre polyline; edge lines on the driving lanes' outer
    borders, each in its lane's direction of travel (right-hand traffic)."""
    normal = _normals(center)
    return [LaneMarking(f"{name}_centre", "broken", "yellow", CENTRE_WIDTH, center, DASH, GAP),
            LaneMarking(f"{name}_edge_right", "solid", "white", EDGE_WIDTH, center - LANE * normal),
            LaneMarking(f"{name}_edge_left", "solid", "white", EDGE_WIDTH, (center + LANE * normal)[::-1])]


def line(a, b, step=2.5):
    n = int(np.ceil(np.hypot(*(np.subtract(b, a))) / step))
    t = np.linspace(0, 1, n + 1)[:, None]
    return np.asarray(a) + t * (np.subtract(b, a))


def junction(cx: float, cy: float, name: str) -> RoadSegment:
    h = LANE
    sq = np.array([[-h, -h], [0, -h], [h, -h], [h, 0], [h, h], [0, h], [-h, h], [-h, 0]]) + (cx, cy)
    v, f = _mesh(sq)
    return RoadSegment(name, "junction", v, f, None, {"road": name})


def build() -> TownLayout:
    """Two east-west streets and three north-south streets meeting in six junctions, plus a
    northern avenue that bends east through a 90-degree curve: about 8,000 m2 of driving lanes,
    room for the 1,000-defect benchmark."""
    h = LANE
    offsets = [-(h + WALK), -h, 0.0, h, h + WALK]
    kinds = ["sidewalk", "driving", "driving", "sidewalk"]
    xs, ys = (-150.0, 0.0, 150.0), (-120.0, 0.0)
    segs: list[RoadSegment] = [junction(x, y, f"junction_{i}{j}") for i, x in enumerate(xs) for j, y in enumerate(ys)]
    streets: dict[str, np.ndarray] = {}
    for j, y in enumerate(ys):
        for i in range(len(xs) - 1):
            streets[f"street{j}_{i}"] = line((xs[i] + h, y), (xs[i + 1] - h, y))
    for i, x in enumerate(xs):
        streets[f"avenue{i}"] = line((x, ys[0] + h), (x, ys[1] - h))
    north = line((0, h), (0, h + 60))
    r = 40.0
    th = np.linspace(np.pi, np.pi / 2, 33)[1:]
    arc = np.column_stack([r + r * np.cos(th), h + 60 + r * np.sin(th)])
    after = line(arc[-1], arc[-1] + (80, 0))[1:]
    streets["north"] = np.concatenate([north, arc, after])
    marks: list[LaneMarking] = []
    for name, center in streets.items():
        segs += strip(center, offsets, kinds, name)
        marks += markings(center, name)
    pts = np.concatenate([s.vertices[:, :2] for s in segs])
    lo, hi = pts.min(0) - 10, pts.max(0) + 10
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 5, 5.0), np.arange(lo[1], hi[1] + 5, 5.0))
    gz = 1.5 * np.sin(gx / 70.0) + 1.0 * np.cos(gy / 55.0) + 0.01 * gx
    terrain = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    rules = ComposeRules(defect_count=40, seed=7, surface="iso8608:B:0.1", merger="cdt",
                         kinds=("driving", "junction"), models_per_type=4)
    return TownLayout("Town", segs, rules, terrain=terrain, markings=marks)


if __name__ == "__main__":
    out = Path(__file__).with_name("town.usda")
    write_layout(build(), out, "roadtwin sample town: street grid, junctions, curve, sidewalks (synthetic, CC0)")
    print(f"wrote {out}")
