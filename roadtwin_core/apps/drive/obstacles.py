"""What stands in the lanes a drive follows: the instances of every prop instancer placed in the
lanes (``roadtwin:prop:place = "lane"``: vehicles stopped in a lane, an OpenDRIVE map's
vehicles). The ego car is solid: ``--route auto`` drives a stretch clear of them, and a route
given by lanes or a poses file that runs into one is refused with one line naming the instance
(before, the drive went through the parked car until the renderer found its camera inside it).

An instance is its prototype's plan bounding box, placed and turned as the instance is
(``TownInstances.corners``). It blocks the route where the body, ``body_width_m`` wide and centred
on the route, would overlap it sideways; then it blocks the arclengths its corners span, widened
by half the body's length each way (the body is centred on the route point).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import RoadtwinError

__all__ = ["Obstacle", "blocked_spans", "check_clear", "free_stretches", "lane_obstacles"]


@dataclass(frozen=True)
class Obstacle:
    corners: tuple[tuple[float, float], ...]   # plan corners (world XY) of the instance's box
    where: str                                 # "<instancer path> instance <i>"

    @property
    def xy(self) -> tuple[float, float]:
        c = np.asarray(self.corners).mean(0)
        return float(c[0]), float(c[1])


def lane_obstacles(town) -> list[Obstacle]:
    """Every instance of the town's instancers placed in the lanes."""
    out = []
    for inst in getattr(town, "instances", []):
        if inst.place != "lane" or inst.corners is None:
            continue
        for i, c in enumerate(np.asarray(inst.corners, dtype=np.float64)):
            out.append(Obstacle(tuple(map(tuple, c)), f"{inst.path} instance {i}"))
    return out


def _along_across(route, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arclength (continued past the route's ends along its end tangents) and signed left offset."""
    s, off = route.project(pts)
    q, t = route.at(s)
    return s + ((pts - q) * t).sum(1), off


def blocked_spans(route, obstacles: list[Obstacle], body_width_m: float, body_length_m: float
                  ) -> list[tuple[float, float, Obstacle]]:
    """(first, last arclength blocked, obstacle) of each obstacle the body would touch on the route,
    in route order."""
    spans = []
    for o in obstacles:
        s, off = _along_across(route, np.asarray(o.corners, dtype=np.float64))
        if off.min() < body_width_m / 2 and off.max() > -body_width_m / 2:
            spans.append((float(s.min() - body_length_m / 2), float(s.max() + body_length_m / 2), o))
    return sorted(spans, key=lambda x: (x[0], x[2].where))


def free_stretches(length_m: float, spans) -> list[tuple[float, float]]:
    """The stretches of [0, length_m] outside every blocked span."""
    out, at = [], 0.0
    for a, b, _ in spans:
        if a > at:
            out.append((at, min(a, length_m)))
        at = max(at, b)
        if at >= length_m:
            break
    if at < length_m:
        out.append((at, length_m))
    return [(a, b) for a, b in out if b > a]


def check_clear(route, obstacles: list[Obstacle], body_width_m: float, body_length_m: float) -> None:
    """One line naming the first standing instance the route runs into, if any."""
    spans = [sp for sp in blocked_spans(route, obstacles, body_width_m, body_length_m)
             if sp[1] >= 0.0 and sp[0] <= route.length]
    if spans:
        a, b, o = spans[0]
        x, y = o.xy
        raise RoadtwinError(f"route ({route.source}) runs into {o.where}, which stands in the lane at "
                            f"x = {x:.2f}, y = {y:.2f} (s = {max(a, 0.0):.1f} m): give lanes or a poses file around it")
