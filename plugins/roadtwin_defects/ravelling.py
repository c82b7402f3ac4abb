"""Ravelling: a wheel-path strip whose surface course has worn away, exposing coarse aggregate.

Why a type of its own: ravelling (ASTM D6433's "raveling": aggregate dislodged, binder lost) runs
along the wheel paths for metres, as wide as a tyre path or two, and as deep as the surface
course. road_defects_br labels such strips as pothole on one train road (RS_290), which holds 95 %
of the train frames' pothole pixels (docs/perception/efficientnet/zeroshot_select/): a twin whose
potholes are only compact holes cannot teach a model that object. Shape: the rut's stadium with
a cosine-bell section (so the rut's closed-form volume holds), longer (3-15 m), wider (0.4-1.1
m), shallow (1-3 cm), with blunt ends and more lateral wander; look: the pothole interior's
exposed aggregate (roadtwin_core/looks/catalog.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import field

from .rut import Rut


class Ravelling(Rut):
    name = "ravelling"
    material = "pothole"      # the catalog material it wears (contracts.DefectType): lost surface course: the pothole's exposed aggregate
    description = "Wheel-path strip of lost surface course (exposed aggregate) along travel (+x)."

    @dataclass
    class Params(Rut.Params):
        length_m: float = field(6.0, lo=0.1, hi=30.0, doc="extent along travel (+x)")
        width_m: float = field(0.7, lo=0.05, hi=3.0, doc="extent across travel (+y)")
        depth_m: float = field(0.02, lo=0.0005, hi=0.1, doc="depth along the axis (the surface course lost)")
        taper_m: float = field(0.4, lo=0.005, hi=25.0, doc="length of each tapering end cap (<= length/2)")
        wander_m: float = field(0.05, lo=0.0, hi=1.0, doc="amplitude of the seeded lateral wander")

    def sample_params(self, rng: np.random.Generator) -> "Ravelling.Params":
        width = rng.uniform(0.4, 1.1)
        length = rng.uniform(max(3.0, 4.0 * width), 15.0)
        return self.Params(length_m=length, width_m=width, depth_m=rng.uniform(0.01, 0.03),
                           taper_m=length * rng.uniform(0.03, 0.1), wander_m=rng.uniform(0.02, 0.1))
