"""Rut: a long shallow wheel-path groove along travel (+x).

Why this shape: rutting is permanent deformation under wheel paths, so it is long along the
lane (2-8 m), about a tyre-path wide (0.3-0.8 m), shallow (1-4 cm) and smooth. The footprint is
a stadium with half-elliptical end caps of length ``taper_m``; depth is a cosine bell of the
normalised distance ``u`` from the axis (``|y|/b`` along the straight part, the elliptical
radius in the caps), so the cross-section is smooth and the groove tapers out at both ends. A
small seeded lateral wander ``y += A sin(2 pi x / lambda + phi)`` (a shear: area and volume are
kept) keeps it from looking ruled. The mesh has rows on level sets of ``u`` and is triangulated
with x compressed, so its triangles are long along travel, where the surface barely changes: a
few hundred to ~1500 triangles whatever the length. Closed-form volume:
``D b (L - 2T) + pi T b D (1/2 - 2/pi^2)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import DefectModel, RoadtwinError, check_params, field

from ._mesh import build_defect, cosine_bell, resample_closed


class Rut:
    name = "rut"
    material = "worn"      # the catalog material it wears (contracts.DefectType): the worn asphalt around it
    description = "Long shallow wheel-path groove along travel (+x), smooth cross-section."
    along_travel = True     # placed with the lane's direction (contracts.DefectType)

    @dataclass
    class Params:
        length_m: float = field(4.0, lo=0.1, hi=20.0, doc="extent along travel (+x)")
        width_m: float = field(0.5, lo=0.05, hi=3.0, doc="extent across travel (+y)")
        depth_m: float = field(0.02, lo=0.0005, hi=0.3, doc="depth along the axis")
        taper_m: float = field(0.8, lo=0.005, hi=25.0, doc="length of each tapering end cap (<= length/2)")
        wander_m: float = field(0.01, lo=0.0, hi=1.0, doc="amplitude of the seeded lateral wander")

    def sample_params(self, rng: np.random.Generator) -> "Rut.Params":
        width = rng.uniform(0.3, 0.8)
        length = rng.uniform(max(2.0, 4.0 * width), 8.0)
        return self.Params(length_m=length, width_m=width, depth_m=rng.uniform(0.01, 0.04),
                           taper_m=length * rng.uniform(0.1, 0.3), wander_m=rng.uniform(0.0, 0.03))

    def generate(self, params: "Rut.Params", rng: np.random.Generator, name: str) -> DefectModel:
        owner = f"defect type {self.name}"
        p = check_params(params, owner)
        L, b, D, T = p.length_m, p.width_m / 2, p.depth_m, p.taper_m
        if T > L / 2:
            raise RoadtwinError(f"{owner}: parameter taper_m ({T}) must be <= length_m / 2 ({L / 2})")
        xc = L / 2 - T  # where the straight part ends
        lam = L * rng.uniform(0.6, 1.2)
        phi = rng.uniform(0.0, 2 * np.pi)
        amp = min(p.wander_m, 0.1 * lam / (2 * np.pi))  # wander slope <= 0.1: stays a simple loop

        def wander(x: np.ndarray) -> np.ndarray:
            return amp * np.sin(2 * np.pi * x / lam + phi)

        def height(xy: np.ndarray) -> np.ndarray:
            x, y = xy[:, 0], xy[:, 1] - wander(xy[:, 0])
            ex = np.maximum(np.abs(x) - xc, 0.0) / T
            return -D * cosine_bell(np.hypot(ex, y / b))

        spacing_x = float(np.clip(L / 80, 0.03, 0.12))  # along travel; across: rows 0.2 b apart

        def stadium(f: float, spacing: float, phase: float) -> np.ndarray:
            """The level set u = f, sheared by the wander, resampled."""
            s = np.linspace(-np.pi / 2, np.pi / 2, 400)
            side = np.linspace(xc, -xc, 800)[1:-1]
            pts = np.vstack([np.column_stack([xc + f * T * np.cos(s), f * b * np.sin(s)]),
                             np.column_stack([side, np.full_like(side, f * b)]),
                             np.column_stack([-xc - f * T * np.cos(s), -f * b * np.sin(s)]),
                             np.column_stack([side[::-1], np.full_like(side, -f * b)])])
            pts[:, 1] += wander(pts[:, 0])
            return resample_closed(pts, spacing, phase)

        loop = stadium(1.0, spacing_x, 0.0)
        rings = [stadium(f, spacing_x, 0.5 * (i + 1)) for i, f in enumerate([0.8, 0.6, 0.4, 0.2])]
        axis_x = np.linspace(-xc, xc, max(2, int(round(2 * xc / spacing_x)) + 1))
        axis = np.column_stack([axis_x, wander(axis_x)])
        return build_defect(name=name, defect_type=self.name, params=p, loop=loop, height=height,
                            extra_points=np.vstack(rings + [axis, [[0.0, wander(np.zeros(1))[0]]]]),
                            max_area=None, min_angle=25.0, margin=0.05 * b,
                            stretch=spacing_x / (0.2 * b))
