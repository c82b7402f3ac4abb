"""Bump: a speed bump / hump across the lane (positive height).

Why this shape: traffic-calming bumps are defined by their cross-section along travel (+x) —
circular arc or parabola of chord ``length_m`` and rise ``height_m`` (0.3-0.9 m bumps, 3-4 m
humps) — extruded across ``width_m`` and tapered at the ends. One normalised coordinate
``u = sqrt((x/a)^2 + |y/b|^m)`` does both: in the middle ``u ~ |x|/a`` (the exact profile), near
``|y| = b`` the large exponent ``m`` rounds the ends, and ``u = 1`` on the footprint, where every
profile is exactly 0.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import DefectModel, RoadtwinError, check_params, field

from ._mesh import build_defect, closed_length, cosine_bell, loop_spacing, resample_closed

PROFILES = ("circular", "parabolic", "cosine")


class Bump:
    name = "bump"
    material = "asphalt"      # the catalog material it wears (contracts.DefectType): fresh asphalt
    description = "Speed bump/hump across the lane: circular, parabolic or cosine cross-section."
    along_travel = True     # placed with the lane's direction (contracts.DefectType)

    @dataclass
    class Params:
        length_m: float = field(0.9, lo=0.05, hi=10.0, doc="extent along travel (+x)")
        width_m: float = field(3.5, lo=0.1, hi=15.0, doc="extent across the lane (+y)")
        height_m: float = field(0.07, lo=0.002, hi=0.3, doc="rise at the crest")
        end_exponent: float = field(12.0, lo=2.0, hi=64.0, doc="how square the ends are (2 = ellipse)")
        profile: str = field("circular", doc="cross-section along travel: circular | parabolic | cosine")

    def sample_params(self, rng: np.random.Generator) -> "Bump.Params":
        if rng.random() < 0.5:  # short speed bump
            length, height = rng.uniform(0.3, 0.9), rng.uniform(0.05, 0.10)
        else:  # long speed hump / table
            length, height = rng.uniform(2.5, 4.0), rng.uniform(0.06, 0.10)
        return self.Params(length_m=length, width_m=rng.uniform(2.5, 4.0), height_m=height,
                           end_exponent=rng.uniform(8.0, 20.0), profile=str(rng.choice(PROFILES)))

    def generate(self, params: "Bump.Params", rng: np.random.Generator, name: str) -> DefectModel:
        owner = f"defect type {self.name}"
        p = check_params(params, owner)
        a, b, H, m = p.length_m / 2, p.width_m / 2, p.height_m, p.end_exponent
        if p.profile not in PROFILES:
            raise RoadtwinError(f"{owner}: parameter profile must be one of {', '.join(PROFILES)}, got {p.profile!r}")
        if p.profile == "circular" and H > a:
            raise RoadtwinError(f"{owner}: parameter height_m ({H}) must be <= length_m / 2 for a circular profile")

        def profile(u: np.ndarray) -> np.ndarray:
            u = np.clip(u, 0.0, 1.0)
            if p.profile == "parabolic":
                return H * (1.0 - u * u)
            if p.profile == "cosine":
                return H * cosine_bell(u)
            rc = (a * a + H * H) / (2 * H)  # circle through (+-a, 0) and (0, H)
            return np.sqrt(np.maximum(rc * rc - (u * a) ** 2, 0.0)) - (rc - H)

        def height(xy: np.ndarray) -> np.ndarray:
            return profile(np.sqrt((xy[:, 0] / a) ** 2 + np.abs(xy[:, 1] / b) ** m))

        t = np.linspace(0.0, 2 * np.pi, 8192, endpoint=False)

        def level_set(f: float) -> np.ndarray:  # the curve u = f
            return np.column_stack([a * f * np.cos(t),
                                    b * np.sign(np.sin(t)) * (f * np.abs(np.sin(t))) ** (2 / m)])

        dense = level_set(1.0)
        h = loop_spacing(closed_length(dense), lo=0.01, hi=0.2, points=180)
        # Level sets of u (nested footprints) carry the cross-section with few triangles.
        rings = [resample_closed(level_set(f), 1.6 * h, phase=0.5 * i)
                 for i, f in enumerate([0.85, 0.65, 0.45, 0.25])]
        spine = np.column_stack([np.zeros(41), np.linspace(-0.9 * b, 0.9 * b, 41)])
        return build_defect(name=name, defect_type=self.name, params=p, loop=resample_closed(dense, h),
                            height=height, extra_points=np.vstack(rings + [spine]),
                            max_area=4 * a * b / 500, margin=0.2 * h)
