"""Depression: a shallow, wide, smooth dip with an elliptical footprint.

Why this shape: settlements and subsidence are broad (1-3 m) and shallow (1-4 cm) with no edge
to speak of, so the profile is a cosine bell ``-D (1 + cos(pi u)) / 2`` in the elliptical radius
``u``: deepest (exactly ``depth_m``) at the centre, meeting the road with zero slope. Its volume
has a closed form, ``pi a b D (1/2 - 2/pi^2)``, which the tests use as a reference.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import DefectModel, check_params, field

from ._mesh import build_defect, closed_length, cosine_bell, loop_spacing, resample_closed


class Depression:
    name = "depression"
    material = "worn"      # the catalog material it wears (contracts.DefectType): the worn asphalt around it
    description = "Shallow wide smooth dip (settlement), elliptical, cosine-bell profile."

    @dataclass
    class Params:
        length_m: float = field(2.0, lo=0.05, hi=20.0, doc="footprint axis along +x")
        width_m: float = field(1.5, lo=0.05, hi=20.0, doc="footprint axis along +y")
        depth_m: float = field(0.02, lo=0.0005, hi=0.3, doc="depth at the centre")

    def sample_params(self, rng: np.random.Generator) -> "Depression.Params":
        length = rng.uniform(1.0, 3.0)
        return self.Params(length_m=length, width_m=length * rng.uniform(0.5, 1.0),
                           depth_m=rng.uniform(0.01, 0.04))

    def generate(self, params: "Depression.Params", rng: np.random.Generator, name: str) -> DefectModel:
        p = check_params(params, f"defect type {self.name}")
        a, b, D = p.length_m / 2, p.width_m / 2, p.depth_m

        def height(xy: np.ndarray) -> np.ndarray:
            return -D * cosine_bell(np.hypot(xy[:, 0] / a, xy[:, 1] / b))

        t = np.linspace(0.0, 2 * np.pi, 4096, endpoint=False)
        dense = np.column_stack([a * np.cos(t), b * np.sin(t)])
        h = loop_spacing(closed_length(dense), lo=0.01, hi=0.2, points=160)
        return build_defect(name=name, defect_type=self.name, params=p, loop=resample_closed(dense, h),
                            height=height, extra_points=np.zeros((1, 2)),
                            max_area=np.pi * a * b / 300, margin=0.2 * h)
