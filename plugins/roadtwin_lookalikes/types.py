"""The look-alike types: surface features a detector mistakes for defects, which are not.

Each is a defect type by contract (``name``, ``Params``, ``sample_params``, ``generate``), so a
layout weights it like any defect (``roadtwin:rules:weight:oil_stain = 2``) and compose places,
merges and binds it the same way. Three optional attributes tell the core what it is:

* ``semantic_class = "road_lookalike"``: the stage labels the instance
  ``["road", "road_lookalike", <type>]`` (not ``road_defect``), so a USD consumer counts it as
  road; class maps list the type names under the road / ego-lane class (never crack or pothole);
* ``along_travel = True``: placed with the lane's direction (tyre marks, paint, joint seams);
* ``material``: the catalog finish it wears (tar, oil, rubber, paint, water, debris).

Sizes are what a survey camera sees on Brazilian two-lane highways: drips and stains 0.2-1.5 m,
tar-sealed crack bands 3-8 cm wide, skid marks 15-30 cm wide and metres long, paint dashes
10-20 cm x 1-4 m.

Every type shares one ``generate`` (check the parameters, draw a footprint, mesh it flush, see
``_shapes.flush_model``); a family differs only in its ``Params`` and its ``_footprint``. A
subclass tunes its family through class attributes (sample ranges, film height).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadtwin_core import RoadtwinError, check_params, field

from ._shapes import Footprint, band_footprint, blob, rectangle, walk

SEMANTIC_CLASS = "road_lookalike"


class _LookAlike:
    """What every look-alike type shares: it labels itself road, and meshes its footprint flush."""

    name = ""
    description = ""
    semantic_class = SEMANTIC_CLASS
    along_travel = False

    def _footprint(self, p, rng: np.random.Generator) -> Footprint:
        raise NotImplementedError

    def generate(self, params, rng: np.random.Generator, name: str):
        p = check_params(params, f"look-alike type {self.name}")
        return self._footprint(p, rng).model(name, self.name, p)


class _Blob(_LookAlike):
    """Irregular blob footprint (stains, water, debris)."""

    _size = (0.2, 1.5)
    _rough = (0.3, 0.8)
    _height = 0.0

    @dataclass
    class Params:
        length_m: float = field(0.8, lo=0.05, hi=10.0, doc="extent along +x")
        width_m: float = field(0.6, lo=0.05, hi=10.0, doc="extent along +y")
        roughness: float = field(0.5, lo=0.0, hi=1.5, doc="outline irregularity (0: an ellipse)")
        height_m: float = field(0.0, lo=0.0, hi=0.005, doc="film thickness above the road (0 = flush)")

    def sample_params(self, rng: np.random.Generator):
        length = rng.uniform(*self._size)
        return self.Params(length_m=length, width_m=length * rng.uniform(0.45, 1.0),
                           roughness=rng.uniform(*self._rough), height_m=self._height)

    def _footprint(self, p, rng: np.random.Generator) -> Footprint:
        return Footprint(blob(rng, p.length_m, p.width_m, p.roughness), min(p.length_m, p.width_m) / 12,
                         p.height_m, bevel_m=0.02)


class OilStain(_Blob):
    name = "oil_stain"
    material = "oil_stain"
    description = "Look-alike: dark engine-oil drip stain, soft irregular blob, flush."


class TarStain(_Blob):
    name = "tar_stain"
    material = "tar"
    description = "Look-alike: spilled or bled tar, near-black glossy blob ~1 mm proud."
    _size = (0.15, 0.8)
    _height = 0.001


class WetPatch(_Blob):
    name = "wet_patch"
    material = "wet_patch"
    description = "Look-alike: damp area (darker, glossier asphalt), large soft blob, flush."
    _size = (0.6, 3.0)
    _rough = (0.4, 0.9)


class Puddle(_Blob):
    name = "puddle"
    material = "puddle"
    description = "Look-alike: standing water in a shallow low spot, mirror-smooth and dark, flush."
    _size = (0.3, 1.6)
    _rough = (0.15, 0.45)


class Debris(_Blob):
    name = "debris"
    material = "debris"
    description = "Look-alike: loose gravel, soil and litter scattered on the lane, ~2 mm."
    _size = (0.3, 1.4)
    _rough = (0.6, 1.2)
    _height = 0.002


class _Band(_LookAlike):
    """A polyline band (tyre marks, tar-sealed cracks)."""

    _length = (0.8, 4.0)
    _width = (0.03, 0.08)
    _step = 0.15
    _tortuosity = (0.15, 0.35)
    _height = 0.001

    @dataclass
    class Params:
        length_m: float = field(2.0, lo=0.1, hi=30.0, doc="length along the band")
        width_m: float = field(0.05, lo=0.01, hi=0.5, doc="band width")
        tortuosity: float = field(0.2, lo=0.0, hi=1.0, doc="heading change per step (rad, std)")
        height_m: float = field(0.001, lo=0.0, hi=0.005, doc="film thickness above the road (0 = flush)")

    def sample_params(self, rng: np.random.Generator):
        return self.Params(length_m=rng.uniform(*self._length), width_m=rng.uniform(*self._width),
                           tortuosity=rng.uniform(*self._tortuosity), height_m=self._height)

    def _footprint(self, p, rng: np.random.Generator) -> Footprint:
        if p.width_m > p.length_m / 2:
            raise RoadtwinError(f"look-alike type {self.name}: parameter width_m ({p.width_m}) must be <= length_m / 2")
        line = walk(rng, p.length_m, max(self._step, 2.5 * p.width_m), p.tortuosity)
        return band_footprint(line, p.width_m, p.height_m)


class SealedCrack(_Band):
    name = "sealed_crack"
    material = "tar"
    description = "Look-alike: crack filled with tar, a meandering near-black band 3-8 cm wide, ~1 mm proud."


class TyreMark(_Band):
    name = "tyre_mark"
    material = "tyre_mark"
    description = "Look-alike: skid or tyre mark, a dark rubber band 15-30 cm wide, metres long, flush."
    along_travel = True
    _length = (2.0, 9.0)
    _width = (0.15, 0.3)
    _step = 0.6
    _tortuosity = (0.01, 0.05)
    _height = 0.0


class PatchSeam(_LookAlike):
    """The tar-sealed joint around a repair: three or two sides of a rectangle, or one straight
    joint (a footprint may not enclose road, so never all four sides)."""

    name = "patch_seam"
    material = "tar"
    description = "Look-alike: tar-sealed joint of a repair or lane seam (C, L or straight band), ~1 mm proud."
    along_travel = True

    @dataclass
    class Params:
        length_m: float = field(1.5, lo=0.2, hi=20.0, doc="extent of the repair along +x")
        width_m: float = field(1.0, lo=0.2, hi=10.0, doc="extent of the repair along +y")
        sides: int = field(3, lo=1, hi=3, doc="sides of the rectangle sealed (1: a straight joint)")
        band_m: float = field(0.04, lo=0.01, hi=0.15, doc="width of the sealed band")
        height_m: float = field(0.001, lo=0.0, hi=0.005, doc="film thickness above the road")

    def sample_params(self, rng: np.random.Generator) -> "PatchSeam.Params":
        return self.Params(length_m=rng.uniform(0.6, 3.5), width_m=rng.uniform(0.5, 2.5),
                           sides=int(rng.integers(1, 4)), band_m=rng.uniform(0.02, 0.06), height_m=0.001)

    def _footprint(self, p, rng: np.random.Generator) -> Footprint:
        # the repair's corners counter-clockwise from (+x, +y); a seam of n sides runs through the last n + 1
        corners = np.roll(rectangle(p.length_m, p.width_m), -1, axis=0)
        return band_footprint(corners[3 - int(p.sides):], p.band_m, p.height_m)


class WornPaint(_LookAlike):
    """A lane-paint dash worn through to the asphalt, or one removed by grinding (ghost paint):
    where the old markings were before a re-striping, a paler, smoother rectangle."""

    name = "worn_paint"
    material = "paint_worn"
    description = "Look-alike: a worn-through paint dash (patchy white on asphalt), ~1 mm proud."
    along_travel = True
    _height = 0.001

    @dataclass
    class Params:
        length_m: float = field(2.0, lo=0.1, hi=10.0, doc="dash length along +x")
        width_m: float = field(0.12, lo=0.05, hi=0.6, doc="dash width along +y")
        height_m: float = field(0.001, lo=0.0, hi=0.005, doc="film thickness above the road")

    def sample_params(self, rng: np.random.Generator):
        return self.Params(length_m=rng.uniform(0.8, 4.0), width_m=rng.uniform(0.1, 0.2), height_m=self._height)

    def _footprint(self, p, rng: np.random.Generator) -> Footprint:
        return Footprint(rectangle(p.length_m, p.width_m), p.width_m / 3, p.height_m,
                         bevel_m=min(0.01, p.width_m / 4))


class GhostPaint(WornPaint):
    name = "ghost_paint"
    material = "paint_ghost"
    description = "Look-alike: ghost of a removed paint dash (ground-off, paler and smoother asphalt), flush."
    _height = 0.0


ALL = (OilStain, TarStain, SealedCrack, TyreMark, WetPatch, Puddle, Debris, PatchSeam, WornPaint, GhostPaint)
