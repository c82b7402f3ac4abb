"""Pothole: an irregular bowl with steep walls and a rough, roughly flat floor.

Why this shape: real potholes are broken-out asphalt — an irregular rim (here a few random
Fourier harmonics on the radius, optionally elongated along +x), near-vertical walls and a floor
that is flat-ish but rough. The depth profile is ``-D (1 - rho^p)^q`` with ``rho`` the radius
normalised by the rim radius in that direction: large ``p`` gives a flat floor, ``q < 1`` a wall
that is steepest at the rim. A smooth seeded noise field roughens the floor and vanishes at the
rim; the result is rescaled so the deepest point is exactly ``depth_m``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import DefectModel, check_params, field

from ._mesh import build_defect, closed_length, loop_spacing, resample_closed

_HARMONICS = np.arange(2, 9)  # rim harmonics k = 2..8 (k = 1 would only shift the centre)


class Pothole:
    name = "pothole"
    material = "pothole"      # the catalog material it wears (contracts.DefectType): coarse exposed aggregate
    description = "Irregular broken-out bowl: steep walls, rough flat-ish floor (2-10 cm deep)."

    @dataclass
    class Params:
        radius_m: float = field(0.25, lo=0.02, hi=2.0, doc="mean rim radius (half the width across)")
        depth_m: float = field(0.05, lo=0.002, hi=0.5, doc="deepest point below the road")
        elongation: float = field(1.3, lo=1.0, hi=4.0, doc="rim length/width ratio, long axis +x")
        irregularity: float = field(0.15, lo=0.0, hi=0.4, doc="summed relative amplitude of rim harmonics")
        wall_exponent: float = field(6.0, lo=1.0, hi=30.0, doc="p in -D(1-rho^p)^q; larger: flatter floor")
        wall_shape: float = field(0.6, lo=0.2, hi=3.0, doc="q in -D(1-rho^p)^q; < 1: steepest at the rim")
        roughness_m: float = field(0.004, lo=0.0, hi=0.05, doc="amplitude of the seeded floor roughness")

    def sample_params(self, rng: np.random.Generator) -> "Pothole.Params":
        depth = rng.uniform(0.02, 0.10)
        return self.Params(radius_m=rng.uniform(0.10, 0.50), depth_m=depth,
                           elongation=rng.uniform(1.0, 1.6), irregularity=rng.uniform(0.05, 0.25),
                           wall_exponent=rng.uniform(4.0, 10.0), wall_shape=rng.uniform(0.4, 0.9),
                           roughness_m=min(rng.uniform(0.002, 0.006), depth / 4))

    def generate(self, params: "Pothole.Params", rng: np.random.Generator, name: str) -> DefectModel:
        p = check_params(params, f"defect type {self.name}")
        R, D = p.radius_m, p.depth_m
        # Rim: r(theta) = R (1 + sum a_k cos(k theta + phi_k)), sum |a_k| = irregularity < 1.
        w = rng.uniform(0.5, 1.5, len(_HARMONICS)) / _HARMONICS
        amp = p.irregularity * w / w.sum()
        phase = rng.uniform(0.0, 2 * np.pi, len(_HARMONICS))
        sx, sy = np.sqrt(p.elongation), 1.0 / np.sqrt(p.elongation)  # area-preserving stretch

        def rim_radius(theta: np.ndarray) -> np.ndarray:
            return R * (1.0 + np.cos(np.outer(theta, _HARMONICS) + phase) @ amp)

        # Floor roughness: a few seeded plane waves, wavelengths 3-15 cm (scaled with size).
        k_waves = 8
        lam = np.clip(rng.uniform(0.15, 0.6, k_waves) * R, 0.03, 0.15)
        ang = rng.uniform(0.0, 2 * np.pi, k_waves)
        wphase = rng.uniform(0.0, 2 * np.pi, k_waves)
        wave = (2 * np.pi / lam)[None, :] * np.vstack([np.cos(ang), np.sin(ang)])  # (2, k)
        wamp = lam / lam.sum()

        def height(xy: np.ndarray) -> np.ndarray:
            xs, ys = xy[:, 0] / sx, xy[:, 1] / sy
            rho = np.clip(np.hypot(xs, ys) / rim_radius(np.arctan2(ys, xs)), 0.0, 1.0)
            env = (1.0 - rho ** p.wall_exponent) ** p.wall_shape
            noise = np.cos(xy @ wave + wphase) @ wamp  # in [-1, 1]
            z = -env * np.maximum(D + p.roughness_m * noise, 0.2 * D)
            return z * (D / max(-z.min(), 1e-12))  # deepest point exactly D

        theta = np.linspace(0.0, 2 * np.pi, 2048, endpoint=False)
        r = rim_radius(theta)
        dense = np.column_stack([sx * r * np.cos(theta), sy * r * np.sin(theta)])
        h = loop_spacing(closed_length(dense), lo=0.01, hi=0.06, points=180)
        loop = resample_closed(dense, h)
        # Rings hugging the rim capture the steep wall; the floor is filled by max_area.
        rings = [resample_closed(f * dense, h * s, phase=0.5 * i)
                 for i, (f, s) in enumerate([(0.96, 1.0), (0.88, 1.2), (0.75, 1.5)])]
        area = np.pi * R * R
        max_area = max(area / 500, 0.5 * (1.8 * h) ** 2)
        return build_defect(name=name, defect_type=self.name, params=p, loop=loop, height=height,
                            extra_points=np.vstack(rings + [np.zeros((1, 2))]), max_area=max_area,
                            margin=0.15 * h)
