"""roadtwin_speed_cushion: a complete third-party defect type in one file.

A speed cushion is a raised rectangular pad narrower than a lane, so buses and trucks straddle
it while cars ride over it: a flat top ``height_m`` high, sloped on/off ramps ``ramp_m`` long
along travel (+x) and steeper side slopes ``side_m`` wide across it (+y).

The ``pyproject.toml`` beside this file makes it an installable package and declares the entry
point that roadtwin finds it by::

    [project.entry-points.roadtwin]
    speed_cushion = "roadtwin_speed_cushion"

After ``pip install ./docs/example_plugin`` it shows up in ``roadtwin plugins`` and a layout can
weight it by name (``roadtwin:rules:weight:speed_cushion``). It uses only roadtwin_core's public
API plus numpy and triangle. docs/plugins.md describes every hook a plugin can implement.

Why the mesh is built this way: the surface is piecewise planar (top, two ramps, two sides, with
diagonal creases at the corners), so its outline, the top's outline and the four corner creases
are given to Triangle as constraint edges; every triangle then lies in one plane and the
surface is exact. The outline is densified (no Steiner points on it: flag ``Y``) so the merger
gets a loop with a few cm spacing; vertices 0..n-1 are that loop, at z = 0.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import triangle

from roadtwin_core import DefectModel, RoadtwinError, check_params, field, hookimpl


class SpeedCushion:
    name = "speed_cushion"
    description = "Raised rectangular pad narrower than a lane, with sloped ramps and sides."

    @dataclass
    class Params:
        length_m: float = field(3.0, lo=0.2, hi=10.0, doc="footprint along travel (+x)")
        width_m: float = field(1.8, lo=0.2, hi=5.0, doc="footprint across travel (+y)")
        height_m: float = field(0.07, lo=0.005, hi=0.2, doc="height of the flat top")
        ramp_m: float = field(0.6, lo=0.01, hi=3.0, doc="on/off ramp length along x")
        side_m: float = field(0.25, lo=0.01, hi=1.0, doc="side slope width across y")

    def sample_params(self, rng: np.random.Generator) -> "SpeedCushion.Params":
        return self.Params(length_m=rng.uniform(2.5, 3.7), width_m=rng.uniform(1.6, 1.9),
                           height_m=rng.uniform(0.06, 0.08), ramp_m=rng.uniform(0.45, 0.65),
                           side_m=rng.uniform(0.15, 0.3))

    def generate(self, params: "SpeedCushion.Params", rng: np.random.Generator, name: str) -> DefectModel:
        owner = f"defect type {self.name}"
        p = check_params(params, owner)
        a, b = p.length_m / 2, p.width_m / 2
        if p.ramp_m >= a:
            raise RoadtwinError(f"{owner}: parameter ramp_m must be < length_m / 2, got {p.ramp_m}")
        if p.side_m >= b:
            raise RoadtwinError(f"{owner}: parameter side_m must be < width_m / 2, got {p.side_m}")
        ta, tb = a - p.ramp_m, b - p.side_m  # half sizes of the flat top

        corners = np.array([[a, -b], [a, b], [-a, b], [-a, -b]])  # CCW
        loop = []
        for c0, c1 in zip(corners, np.roll(corners, -1, axis=0)):
            k = max(1, int(np.ceil(np.linalg.norm(c1 - c0) / 0.05)))
            loop.append(c0 + (c1 - c0) * (np.arange(k)[:, None] / k))
        loop = np.vstack(loop)
        n = len(loop)
        corner_idx = [int(np.flatnonzero((loop == c).all(axis=1))[0]) for c in corners]
        top = np.array([[ta, -tb], [ta, tb], [-ta, tb], [-ta, -tb]])
        ring = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
        top_edges = [[n + i, n + (i + 1) % 4] for i in range(4)]
        creases = [[corner_idx[i], n + i] for i in range(4)]
        out = triangle.triangulate({"vertices": np.vstack([loop, top]),
                                    "segments": np.vstack([ring, top_edges, creases])}, "pY")
        xy = out["vertices"]
        # Height: the lower of the ramp and side slopes, capped by the flat top.
        t = np.minimum((a - np.abs(xy[:, 0])) / p.ramp_m, (b - np.abs(xy[:, 1])) / p.side_m)
        z = p.height_m * np.clip(t, 0.0, 1.0)
        return DefectModel(name=name, defect_type=self.name, vertices=np.column_stack([xy, z]),
                           faces=out["triangles"], boundary=np.arange(n), source="parametric",
                           params=dataclasses.asdict(p))


@hookimpl
def roadtwin_register_defect_types(register):
    register(SpeedCushion())
