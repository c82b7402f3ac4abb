"""Crack: a narrow shallow V-groove network grown as a seeded branching random walk.

Why this shape: surface cracks in asphalt are thin (1-3 cm opened up), shallow (0.5-2 cm),
meandering and branching. A trunk random walk (heading mean-reverting, so it does not curl up;
turns capped at 50 deg a step) sprouts side branches at least 45 deg from the parent on both
sides. The network is a tree: every new step keeps a clearance (groove width + 1.5 loop
spacings) from everything already drawn, and a step that would not simply ends that branch. So
the buffered footprint is always ONE polygon without holes (an enclosed road island would need a
hole, which the DefectModel contract forbids), with no outline angle sharper than ~45 deg on
the road side and no gap narrower than 1.5 loop spacings, which keeps a merger's re-triangulated
ring around it well shaped. Cross-section is a
V: depth falls linearly from ``depth_m`` on a centreline to 0 at half the width. Centrelines are
kept as triangle edges, so the groove bottom is sharp with very few triangles.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, MultiLineString, Polygon

from roadtwin_core import DefectModel, RoadtwinError, check_params, field

from ._mesh import build_defect, densify_closed, densify_open


class Crack:
    name = "crack"
    material = "crack"      # the catalog material it wears (contracts.DefectType): the dark crack finish
    description = "Branching hairline-to-open crack network: narrow shallow V-groove tree."

    @dataclass
    class Params:
        extent_m: float = field(1.0, lo=0.05, hi=10.0, doc="length of the trunk (overall extent)")
        width_m: float = field(0.02, lo=0.002, hi=0.1, doc="groove width at the road surface")
        depth_m: float = field(0.01, lo=0.0005, hi=0.1, doc="groove depth on the centreline")
        branches: int = field(3, lo=0, hi=20, doc="number of side branches to try growing")
        tortuosity: float = field(0.25, lo=0.0, hi=1.5, doc="std of the heading change per step (rad)")

    def sample_params(self, rng: np.random.Generator) -> "Crack.Params":
        return self.Params(extent_m=rng.uniform(0.5, 2.0), width_m=rng.uniform(0.01, 0.03),
                           depth_m=rng.uniform(0.005, 0.02), branches=int(rng.integers(0, 5)),
                           tortuosity=rng.uniform(0.15, 0.4))

    def generate(self, params: "Crack.Params", rng: np.random.Generator, name: str) -> DefectModel:
        owner = f"defect type {self.name}"
        p = check_params(params, owner)
        if p.width_m > p.extent_m / 2:
            raise RoadtwinError(f"{owner}: parameter width_m ({p.width_m}) must be <= extent_m / 2")
        w, D = p.width_m, p.depth_m
        spacing = float(np.clip(max(w, p.extent_m / 50), 0.01, 0.04))  # loop spacing
        clearance = w + 1.5 * spacing  # gaps between branches stay >= 1.5 loop spacings
        step = max(1.6 * clearance, p.extent_m / 25)  # a branch clears its parent in one step
        lines = _grow_tree(rng, p.extent_m, step, clearance, int(p.branches), p.tortuosity)
        return groove_network(lines, w, D, spacing, name=name, defect_type=self.name, params=p)


def groove_network(lines: list[np.ndarray], w: float, D: float, spacing: float, *, name: str, defect_type: str,
                   params) -> DefectModel:
    """Centrelines (a tree: no closed loop) -> the model of their V-grooves, ``w`` wide and ``D``
    deep on the centreline: the footprint is their buffer (one polygon without holes), centred on
    its centroid, the centrelines kept as triangle edges so the groove bottoms are sharp."""
    net = MultiLineString([LineString(c) for c in lines])
    foot = net.buffer(w / 2, quad_segs=3).simplify(0.1 * w)
    if not isinstance(foot, Polygon) or len(foot.interiors) or not foot.is_valid:
        raise RoadtwinError(f"defect type {defect_type}: crack network did not buffer to one simple polygon "
                            f"(internal error)")
    loop = densify_closed(np.asarray(foot.exterior.coords)[:-1], spacing)
    # Centre the local frame on the footprint.
    centre = np.asarray(foot.centroid.coords[0])
    loop = loop - centre
    centrelines = [(densify_open(c - centre, spacing), False) for c in lines]
    net = affinity.translate(net, -centre[0], -centre[1])

    def height(xy: np.ndarray) -> np.ndarray:
        d = shapely.distance(net, shapely.points(xy))
        return -D * np.clip(1.0 - d / (w / 2), 0.0, 1.0)

    return build_defect(name=name, defect_type=defect_type, params=params, loop=loop, height=height,
                        extra_lines=centrelines, min_angle=None, margin=0.0)


def _grow_tree(rng: np.random.Generator, extent: float, step: float, clearance: float,
               branches: int, tortuosity: float) -> list[np.ndarray]:
    """Trunk + side branches as polylines; no two come closer than ``clearance`` (a tree).

    Turns are capped at ``_MAX_TURN`` per step and a branch leaves its parent at least
    ``_MIN_JUNCTION`` away from both parent segments, so the footprint has no sharp notch
    (a merger re-triangulating the road around it cannot fix angles the outline itself has).
    """
    heading0 = rng.uniform(0.0, np.pi)
    lines: list[np.ndarray] = []

    def walk(start: np.ndarray, heading: float, n_steps: int, parent: int | None, at: int) -> None:
        pts = [start]
        mean = heading
        for i in range(n_steps):
            if i > 0 or parent is None:
                new = mean + 0.7 * (heading - mean) + rng.normal(0.0, tortuosity)
                heading += float(np.clip(new - heading, -_MAX_TURN, _MAX_TURN))
            q = pts[-1] + step * np.array([np.cos(heading), np.sin(heading)])
            seg = LineString([pts[-1], q])
            others = [c for j, c in enumerate(lines) if not (i == 0 and j == parent)]
            if i == 0 and parent is not None:  # the parent minus the two segments touching `at`
                others += [lines[parent][:at], lines[parent][at + 1:]]
            others.append(np.asarray(pts[:-1]))  # own polyline minus the segment seg continues
            others = [LineString(c) for c in others if len(c) >= 2]
            if others and seg.distance(MultiLineString(others)) < clearance:
                break
            pts.append(q)
        if len(pts) >= 2:
            lines.append(np.asarray(pts))

    n_trunk = max(2, int(round(extent / step)))
    trunk_start = -0.5 * extent * np.array([np.cos(heading0), np.sin(heading0)])
    walk(trunk_start, heading0, n_trunk, None, 0)
    for _ in range(branches):
        parent = int(rng.integers(0, len(lines)))
        c = lines[parent]
        if len(c) < 3:
            continue
        at = int(rng.integers(1, len(c) - 1))
        fwd = np.arctan2(*(c[at + 1] - c[at])[::-1])
        back = np.arctan2(*(c[at - 1] - c[at])[::-1])
        side = 1.0 if rng.random() < 0.5 else -1.0
        # Free wedge on that side, measured from the forward segment towards the backward one.
        span = ((back - fwd) * side) % (2 * np.pi)
        lo, hi = _MIN_JUNCTION, span - _MIN_JUNCTION
        frac = rng.uniform(0.0, 1.0)
        n_steps = max(2, int(round(extent * rng.uniform(0.2, 0.5) / step)))
        if hi < lo:
            continue
        walk(c[at], fwd + side * (lo + frac * (hi - lo)), n_steps, parent, at)
    return lines


_MAX_TURN = np.deg2rad(50.0)
_MIN_JUNCTION = np.deg2rad(45.0)
