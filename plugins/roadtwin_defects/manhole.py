"""Manhole: a circular cover sunk or raised relative to the road, in a flush frame.

Why this shape: a settled (or proud) manhole is a flat cast-iron cover plus its frame ring,
both offset by ``offset_m`` (negative = sunk), meeting the asphalt through a narrow steep band.
A 2.5D height field cannot hold the vertical step, so the band is a linear ramp ``ramp_m`` wide
(a 3 cm step over 1 cm is ~72 deg). The cover edge, the frame's outer edge and the footprint are
exact concentric polygons kept as triangle edges, so the ramp is modelled exactly and the cover
edge can be picked out by radius. Closed-form volume:
``|o| pi (Rf^2 + Rf t + t^2 / 3)`` with ``Rf`` the frame radius and ``t`` the ramp width.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import DefectModel, check_params, field

from ._mesh import build_defect, loop_spacing


def _circle(radius: float, n: int, phase: float = 0.0) -> np.ndarray:
    t = 2 * np.pi * (np.arange(n) + phase) / n
    return np.column_stack([radius * np.cos(t), radius * np.sin(t)])


class Manhole:
    name = "manhole"
    material = "cast_iron"      # the catalog material it wears (contracts.DefectType): the cover
    description = "Circular cover + frame sunk or raised 0.5-3 cm, with a steep ramp to the road."

    @dataclass
    class Params:
        diameter_m: float = field(0.7, lo=0.1, hi=3.0, doc="cover diameter")
        offset_m: float = field(-0.015, lo=-0.2, hi=0.2, doc="cover height vs road, negative = sunk")
        ramp_m: float = field(0.02, lo=0.005, hi=0.3, doc="width of the steep transition band")
        frame_m: float = field(0.06, lo=0.0, hi=0.5, doc="width of the frame ring around the cover")

    def sample_params(self, rng: np.random.Generator) -> "Manhole.Params":
        sign = -1.0 if rng.random() < 0.75 else 1.0  # most covers settle
        return self.Params(diameter_m=rng.uniform(0.6, 0.8), offset_m=sign * rng.uniform(0.005, 0.03),
                           ramp_m=rng.uniform(0.01, 0.03), frame_m=rng.uniform(0.04, 0.10))

    def generate(self, params: "Manhole.Params", rng: np.random.Generator, name: str) -> DefectModel:
        p = check_params(params, f"defect type {self.name}")
        rc = p.diameter_m / 2
        rf = rc + p.frame_m
        ro = rf + p.ramp_m

        def height(xy: np.ndarray) -> np.ndarray:
            r = np.hypot(xy[:, 0], xy[:, 1])
            return p.offset_m * np.clip((ro - r) / p.ramp_m, 0.0, 1.0)

        h = loop_spacing(2 * np.pi * ro, lo=0.01, hi=0.05, points=160)
        n = max(24, int(round(2 * np.pi * ro / h)))
        lines = [(_circle(rf, n, 0.5), True)]
        if p.frame_m > 0.25 * h:
            lines.append((_circle(rc, max(24, int(round(n * rc / rf))), 0.0), True))
        return build_defect(name=name, defect_type=self.name, params=p, loop=_circle(ro, n),
                            height=height, extra_lines=lines, extra_points=np.zeros((1, 2)),
                            max_area=np.pi * ro * ro / 200, margin=0.0)
