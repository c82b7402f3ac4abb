"""Defect parameter priors: per-type distributions of a parametric type's parameters, drawn in
place of the type's own ``sample_params`` ranges (docs/architecture.md, "Defect types").

Why: a parametric type's ranges are a modeller's guess; a survey's labels say what its roads hold.
The built-in ``road_defects_br`` priors are measured from that dataset's train labels through the
survey rig (``bench/defect_priors.py``): its potholes have a median radius of 0.25 m with a long
tail past 1 m, where the pothole type's own draw is uniform in 0.10-0.50 m, and a network trained
on the twin learns the sizes it sees.

A priors file (TOML) holds, per type and parameter, one distribution and an optional clip::

    source = "where the numbers come from"
    [pothole.radius_m]
    lognormal = [0.25, 0.93]     # median, sigma of the log
    clip = [0.08, 1.5]
    [crack.extent_m]
    uniform = [0.5, 3.0]

Parameters a file does not name keep the type's own draw. Draws come from their own generator
(seeded by the model's), so the type's other parameters are the same with and without priors.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RoadtwinError

__all__ = ["FieldPrior", "apply_priors", "load_priors"]

KINDS = ("lognormal", "uniform")


@dataclass(frozen=True)
class FieldPrior:
    """One parameter's distribution: ``lognormal`` (median, sigma of the log) or ``uniform``
    (lo, hi), then clipped to ``clip``."""

    kind: str
    a: float
    b: float
    clip: tuple[float, float] = (-math.inf, math.inf)

    def draw(self, rng: np.random.Generator) -> float:
        v = self.a * math.exp(self.b * rng.standard_normal()) if self.kind == "lognormal" else rng.uniform(self.a, self.b)
        return float(min(max(v, self.clip[0]), self.clip[1]))


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
    if len(kinds) != 1 or set(entry) - {*KINDS, "clip"}:
        raise RoadtwinError(f"{where}: give exactly one of {' | '.join(KINDS)} (and optionally clip)")
    a, b = _pair(entry[kinds[0]], where)
    clip = _pair(entry.get("clip", [-math.inf, math.inf]), where)
    if kinds[0] == "lognormal" and not (a > 0 and b >= 0):
        raise RoadtwinError(f"{where}: lognormal needs median > 0 and sigma >= 0, got {a}, {b}")
    if a > b and kinds[0] == "uniform" or clip[0] > clip[1]:
        raise RoadtwinError(f"{where}: ranges must satisfy lo <= hi")
    return FieldPrior(kinds[0], a, b, clip)


def _pair(value: Any, where: str) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)):
        raise RoadtwinError(f"{where}: expected two numbers, got {value!r}")
    return float(value[0]), float(value[1])


def apply_priors(params: Any, priors: dict[str, FieldPrior], rng: np.random.Generator, owner: str) -> Any:
    """``params`` (a type's Params dataclass) with the named fields redrawn from their priors, in
    the order the dataclass lists them. A name the type lacks raises one line."""
    if not priors:
        return params
    names = [f.name for f in dataclasses.fields(params)]
    unknown = sorted(set(priors) - set(names))
    if unknown:
        raise RoadtwinError(f"{owner}: defect priors name parameters it does not have: {', '.join(unknown)} "
                            f"(it has {', '.join(names)})")
    changes = {}
    for name in names:
        if name in priors:
            value = priors[name].draw(rng)
            changes[name] = type(getattr(params, name))(round(value) if isinstance(getattr(params, name), int) else value)
    return dataclasses.replace(params, **changes)
