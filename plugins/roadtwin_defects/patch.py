"""Patch: a repaired rectangle of fresh asphalt, flush or slightly proud of the road.

Why it exists: patches are the commonest false positive of road-defect detectors (a dark,
sharp-edged region that is not a defect), so a twin needs them as distractors. The footprint is
a rectangle ``length_m`` along +x by ``width_m`` along +y with corners rounded off by
``corner_m`` (saw-cut repairs are sharp, hand-laid ones rounded). The top is flat at
``height_m`` (0: flush) and meets the road through a bevel ``bevel_m`` wide in which the height
rises linearly with the distance from the footprint edge. The top edge (the footprint inset by
the bevel, a rounded rectangle with corner radius ``max(corner - bevel, 0)``) is kept as
triangle edges, so the flat top and the straight bevels are modelled exactly. Volume:
``(H / t) * integral_0^t A(s) ds`` with ``A(s)`` the area of the footprint inset by ``s``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import DefectModel, RoadtwinError, check_params, field

from ._mesh import build_defect, densify_closed, loop_spacing


def rounded_rectangle(half_x: float, half_y: float, corner: float, arc_step: float) -> np.ndarray:
    """CCW outline of a rectangle centred at 0 with quarter-circle corners (sharp if corner 0)."""
    if corner <= 0:
        return np.array([[half_x, -half_y], [half_x, half_y], [-half_x, half_y], [-half_x, -half_y]])
    k = max(2, int(np.ceil(0.5 * np.pi * corner / arc_step)))
    t = np.linspace(0.0, 0.5 * np.pi, k + 1)
    arc = corner * np.column_stack([np.cos(t), np.sin(t)])
    centres = [(half_x - corner, half_y - corner), (-(half_x - corner), half_y - corner),
               (-(half_x - corner), -(half_y - corner)), (half_x - corner, -(half_y - corner))]
    pts = []
    for i, c in enumerate(centres):  # quadrant i: the arc turned by i * 90 degrees
        rot = np.array([[np.cos(i * np.pi / 2), -np.sin(i * np.pi / 2)], [np.sin(i * np.pi / 2), np.cos(i * np.pi / 2)]])
        pts.append(np.asarray(c) + arc @ rot.T)
    out = np.vstack(pts)
    keep = np.r_[True, np.linalg.norm(np.diff(out, axis=0), axis=1) > 1e-12]  # corner = half side: arcs touch
    out = out[keep]
    if np.linalg.norm(out[0] - out[-1]) <= 1e-12:
        out = out[:-1]
    return out


def inner_distance(xy: np.ndarray, half_x: float, half_y: float, corner: float) -> np.ndarray:
    """Distance from points inside the rounded rectangle to its edge (negative outside)."""
    qx = np.abs(xy[:, 0]) - (half_x - corner)
    qy = np.abs(xy[:, 1]) - (half_y - corner)
    outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0)) + np.minimum(np.maximum(qx, qy), 0.0) - corner
    return -outside


class Patch:
    name = "patch"
    material = "patch"      # the catalog material it wears (contracts.DefectType): newer, darker asphalt
    description = "Repaired rectangle of fresh asphalt: flush or up to ~1 cm proud, short edge bevel."

    @dataclass
    class Params:
        length_m: float = field(1.5, lo=0.1, hi=20.0, doc="extent along +x")
        width_m: float = field(1.0, lo=0.1, hi=20.0, doc="extent along +y")
        height_m: float = field(0.004, lo=0.0, hi=0.05, doc="top above the road (0 = flush)")
        bevel_m: float = field(0.03, lo=0.005, hi=0.5, doc="width of the edge ramp from the road to the top")
        corner_m: float = field(0.05, lo=0.0, hi=2.0, doc="corner rounding radius (0 = sharp saw-cut corners)")

    def sample_params(self, rng: np.random.Generator) -> "Patch.Params":
        flush = rng.random() < 0.4
        return self.Params(length_m=rng.uniform(0.4, 3.0), width_m=rng.uniform(0.4, 3.0),
                           height_m=0.0 if flush else rng.uniform(0.002, 0.010), bevel_m=rng.uniform(0.02, 0.05),
                           corner_m=0.0 if rng.random() < 0.3 else rng.uniform(0.02, 0.15))

    def generate(self, params: "Patch.Params", rng: np.random.Generator, name: str) -> DefectModel:
        owner = f"defect type {self.name}"
        p = check_params(params, owner)
        a, b, c, t, H = p.length_m / 2, p.width_m / 2, p.corner_m, p.bevel_m, p.height_m
        if c > min(a, b):
            raise RoadtwinError(f"{owner}: parameter corner_m ({c}) must be <= min(length_m, width_m) / 2")
        if t >= 0.9 * min(a, b):
            raise RoadtwinError(f"{owner}: parameter bevel_m ({t}) must be < 0.45 * min(length_m, width_m)")
        h = loop_spacing(4 * (a + b), lo=0.01, hi=0.04, points=120)  # a few cm: the merger needs it
        loop = densify_closed(rounded_rectangle(a, b, c, h / 4), h)  # fine arcs: area ~exact
        lines = []
        if H > 0:
            top = densify_closed(rounded_rectangle(a - t, b - t, max(c - t, 0.0), h / 4), h)
            lines.append((top, True))

        def height(xy: np.ndarray) -> np.ndarray:
            return H * np.clip(inner_distance(xy, a, b, c) / t, 0.0, 1.0)

        return build_defect(name=name, defect_type=self.name, params=p, loop=loop, height=height,
                            extra_lines=lines, extra_points=np.zeros((1, 2)),
                            max_area=4 * a * b / 40, margin=0.0)  # flat top: only the bevel needs small triangles
