"""Defect parameter priors: per-type distributions of a parametric type's parameters, drawn in
place of the type's own ``sample_params`` ranges (docs/architecture.md, "Parameters").

Why: a parametric type's ranges are a modeller's guess; a survey's labels say what its roads hold.
The built-in ``road_defects_br`` priors are measured from that dataset's train labels through the
survey rig (``bench/defect_priors.py``): its potholes have a median radius of 0.25 m with a long
tail past 1 m, where the pothole type's own draw is uniform in 0.10-0.50 m, and a network trained
on the twin learns the sizes it sees.

A priors file (TOML) holds, per type and parameter, one distribution and an optional clip::

    source = "where the numbers come from"
    [pothole.radius_m]
    lognormal = [0.25, 0.93]     # median, sigma of the log
    truncate = [0.08, 1.5]       # drawn within (or clip = [...]: beyond set to the ends)
    [crack.extent_m]
    uniform = [0.5, 3.0]

Parameters a file does not name keep the type's own draw. Draws come from their own generator
(seeded by the model's), so the type's other parameters are the same with and without priors.
A prior must stay within its parameter's bounds whatever it draws (clip it): a tail that reached
past them would fail only for some seeds. Drawn values go through ``apply_params`` like a
layout's (an integer field takes the rounded draw).
"""
from __future__ import annotations

import dataclasses
import math
import numbers
import tomllib
from statistics import NormalDist
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RoadtwinError
from ..params import apply_params

__all__ = ["FieldPrior", "apply_priors", "load_priors"]

KINDS = ("lognormal", "uniform")


@dataclass(frozen=True)
class FieldPrior:
    """One parameter's distribution: ``lognormal`` (median, sigma of the log) or ``uniform``
    (lo, hi), then clipped to ``clip`` (values beyond it set to its ends) or, with ``truncate``,
    drawn within it (the distribution's shape kept between the ends, no pile-up at them)."""

    kind: str
    a: float
    b: float
    clip: tuple[float, float] = (-math.inf, math.inf)
    truncate: bool = False

    def draw(self, rng: np.random.Generator) -> float:
        lo, hi = self.clip
        if self.truncate and self.kind == "lognormal" and self.b > 0:
            unit = NormalDist()
            cdf = [unit.cdf((math.log(x) - math.log(self.a)) / self.b) if 0 < x < math.inf else float(x > 0)
                   for x in (lo, hi)]
            u = min(max(rng.uniform(cdf[0], cdf[1]), 1e-15), 1 - 1e-15)
            v = self.a * math.exp(self.b * unit.inv_cdf(u))
        elif self.truncate and self.kind == "uniform":
            v = rng.uniform(max(self.a, lo), min(self.b, hi))
        else:
            v = self.a * math.exp(self.b * rng.standard_normal()) if self.kind == "lognormal" else rng.uniform(self.a, self.b)
        return float(min(max(v, lo), hi))


def load_priors(spec: str | Path) -> tuple[dict[str, dict[str, FieldPrior]], str]:
    """``builtin:NAME`` or a TOML file -> ({type: {parameter: prior}}, source text). Bad files
    and entries raise one line naming the file and the entry."""
    spec = str(spec)
    if spec.startswith("builtin:"):
        name = spec[len("builtin:"):]
        ref = resources.files(__package__).joinpath("defect_priors", f"{name}.toml")
        if not ref.is_file():
            known = sorted(p.name[:-5] for p in resources.files(__package__).joinpath("defect_priors").iterdir()
                           if p.name.endswith(".toml"))
            raise RoadtwinError(f"--defect-priors: no built-in priors {name!r} (known: {', '.join(known)})")
        text, where = ref.read_text(), spec
    else:
        path = Path(spec)
        if not path.is_file():
            raise RoadtwinError(f"{path}: defect priors file not found")
        text, where = path.read_text(), str(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RoadtwinError(f"{where}: not valid TOML ({e})") from None
    source = str(doc.pop("source", where))
    priors: dict[str, dict[str, FieldPrior]] = {}
    for dtype, fields in doc.items():
        if not isinstance(fields, dict):
            raise RoadtwinError(f"{where}: {dtype}: expected a table of parameters")
        priors[dtype] = {name: _field_prior(entry, f"{where}: {dtype}.{name}") for name, entry in fields.items()}
    return priors, source


def _field_prior(entry: Any, where: str) -> FieldPrior:
    kinds = [k for k in KINDS if isinstance(entry, dict) and k in entry]
    if len(kinds) != 1 or set(entry) - {*KINDS, "clip", "truncate"} or {"clip", "truncate"} <= set(entry):
        raise RoadtwinError(f"{where}: give exactly one of {' | '.join(KINDS)} (and optionally clip or truncate)")
    a, b = _pair(entry[kinds[0]], where)
    truncate = "truncate" in entry
    clip = _pair(entry.get("truncate" if truncate else "clip", [-math.inf, math.inf]), where)
    if not (math.isfinite(a) and math.isfinite(b)) or math.isnan(clip[0]) or math.isnan(clip[1]):
        raise RoadtwinError(f"{where}: {kinds[0]} needs finite numbers, got {a}, {b}")
    if kinds[0] == "lognormal" and not (a > 0 and b >= 0):
        raise RoadtwinError(f"{where}: lognormal needs median > 0 and sigma >= 0, got {a}, {b}")
    if (kinds[0] == "uniform" and a > b) or clip[0] > clip[1]:
        raise RoadtwinError(f"{where}: ranges must satisfy lo <= hi")
    if truncate and (clip[0] >= clip[1] or (kinds[0] == "uniform" and (clip[0] >= b or clip[1] <= a))):
        raise RoadtwinError(f"{where}: truncate must leave part of the distribution (lo < hi, overlapping it)")
    return FieldPrior(kinds[0], a, b, clip, truncate)


def _pair(value: Any, where: str) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise RoadtwinError(f"{where}: expected two numbers, got {value!r}")
    return float(value[0]), float(value[1])


def _reach(prior: FieldPrior) -> tuple[float, float]:
    """The values a prior can draw: its distribution's support within its clip."""
    lo, hi = (0.0, math.inf) if prior.kind == "lognormal" else (prior.a, prior.b)
    return max(lo, prior.clip[0]), min(hi, prior.clip[1])


def _check_field(f: dataclasses.Field, prior: FieldPrior, owner: str) -> type:
    """The field's type (that of its default, as ``apply_params`` reads it); one line if the
    field is not a number or the prior can draw outside its bounds."""
    kind = type(f.default)
    if f.default is dataclasses.MISSING or kind is bool or not issubclass(kind, numbers.Real):
        raise RoadtwinError(f"{owner}: defect prior for {f.name}: the parameter is not a number")
    lo, hi = _reach(prior)
    lo_b, hi_b = f.metadata.get("lo"), f.metadata.get("hi")
    if (lo_b is not None and lo < lo_b) or (hi_b is not None and hi > hi_b):
        raise RoadtwinError(f"{owner}: defect prior for {f.name} draws {lo:g}..{hi:g}, beyond the parameter's "
                            f"bounds {lo_b}..{hi_b} (give it a clip within them)")
    return kind


def apply_priors(params: Any, priors: dict[str, FieldPrior], rng: np.random.Generator, owner: str) -> Any:
    """``params`` (a type's Params dataclass) with the named fields redrawn from their priors, in
    the order the dataclass lists them, checked like a layout's values. A name the type lacks, a
    field that is not a number and a prior reaching past the field's bounds raise one line."""
    if not priors:
        return params
    fields = dataclasses.fields(params)
    names = [f.name for f in fields]
    unknown = sorted(set(priors) - set(names))
    if unknown:
        raise RoadtwinError(f"{owner}: defect priors name parameters it does not have: {', '.join(unknown)} "
                            f"(it has {', '.join(names)})")
    changes = {}
    for f in fields:
        if f.name in priors:
            kind = _check_field(f, priors[f.name], owner)
            value = priors[f.name].draw(rng)
            changes[f.name] = round(value) if issubclass(kind, numbers.Integral) else value
    return apply_params(params, changes, owner)
