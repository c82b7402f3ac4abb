"""What stands in the lanes a drive follows: the instances of every prop instancer placed in the
lanes (``roadtwin:prop:place = "lane"``: vehicles stopped in a lane, an OpenDRIVE map's
vehicles). The ego car is solid: ``--route auto`` drives a stretch clear of them, and a route
given by lanes or a poses file that runs into one is refused with one line naming the instance
(before, the drive went through the parked car until the renderer found its camera inside it).

A standing instance blocks the route where its plan circle (``TownInstances.radii``) comes
within half the body's width of the route polyline; it then blocks the arclengths where the
body (its length centred on the route point) would overlap that circle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import RoadtwinError

__all__ = ["Obstacle", "blocked_spans", "check_clear", "free_stretches", "lane_obstacles"]


@dataclass(frozen=True)
class Obstacle:
    xy: tuple[float, float]
    radius_m: float
    where: str          # "<instancer path> instance <i>"


def lane_obstacles(town) -> list[Obstacle]:
    """Every instance of the town's instancers placed in the lanes."""
    out = []
    for inst in getattr(town, "instances", []):
        if inst.place != "lane":
            continue
        for i, (p, r) in enumerate(zip(np.asarray(inst.positions), np.asarray(inst.radii))):
            out.append(Obstacle((float(p[0]), float(p[1])), float(r), f"{inst.path} instance {i}"))
    return out


def blocked_spans(route, obstacles: list[Obstacle], body_width_m: float, body_length_m: float
                  ) -> list[tuple[float, float, Obstacle]]:
    """(first, last arclength blocked, obstacle) of each obstacle the body would touch on the route,
    in route order."""
    if not obstacles:
        return []
    xy = np.array([o.xy for o in obstacles])
    r = np.array([o.radius_m for o in obstacles])
    s, _ = route.project(xy)
    near, _ = route.at(s)
    gap = np.linalg.norm(xy - near, axis=1)
    hit = gap < r + body_width_m / 2
    reach = r + body_length_m / 2
    spans = [(float(s[k] - reach[k]), float(s[k] + reach[k]), obstacles[k]) for k in np.flatnonzero(hit)]
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
        raise RoadtwinError(f"route ({route.source}) runs into {o.where}, which stands in the lane at "
                            f"x = {o.xy[0]:.2f}, y = {o.xy[1]:.2f} (s = {max(a, 0.0):.1f} m): give lanes or a poses "
                            f"file around it")
