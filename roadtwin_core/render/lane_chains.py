"""Continuous lanes from a town's per-segment lane centrelines, and where points lie along them.

Why its own module: the view sampler, the survey-rig writer and the ego-lane labeller all need a
road's lanes as one polyline each (a layout cuts a road every 25 m), and the arc length and
lateral offset of points on them; numpy only. See docs/architecture.md (rendering).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .cameras import Lane

__all__ = ["ChainedLane", "chain_lanes", "lane_ahead", "project_to_lane", "unit_vector"]


@dataclass
class ChainedLane(Lane):
    """A continuous lane made of consecutive segments' centrelines; ``starts[k]`` is the arc
    length where ``segments[k]`` begins."""

    segments: tuple[str, ...] = ()
    starts: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def segment_at(self, s: float) -> str:
        k = int(np.searchsorted(self.starts, s, side="right")) - 1
        return self.segments[min(max(k, 0), len(self.segments) - 1)]


def chain_lanes(lanes: Sequence[Lane], tol_m: float = 0.05, max_turn_deg: float = 30.0) -> list[ChainedLane]:
    """Join lanes whose end meets another's start (within ``tol_m``, heading change below
    ``max_turn_deg``) into continuous lanes. A lane end with several candidate successors (a
    junction) or a successor with several predecessors ends the chain there; a closed ring is
    cut at its first lane (in input order). Output order follows the first lane of each chain in
    the input order, so it is deterministic."""
    lanes = [l for l in lanes if len(l.points) >= 2 and l.length > 1e-6]
    if not lanes:
        return []
    starts = np.array([l.points[0] for l in lanes])
    ends = np.array([l.points[-1] for l in lanes])
    d_in = np.array([unit_vector(l.points[1] - l.points[0]) for l in lanes])
    d_out = np.array([unit_vector(l.points[-1] - l.points[-2]) for l in lanes])
    gap = np.linalg.norm(ends[:, None, :] - starts[None, :, :], axis=-1)
    turn_ok = (d_out @ d_in.T) >= math.cos(math.radians(max_turn_deg))
    link = (gap <= tol_m) & turn_ok
    np.fill_diagonal(link, False)
    succ = np.full(len(lanes), -1)
    ok = (link.sum(1) == 1)
    succ[ok] = link[ok].argmax(1)
    npred = np.zeros(len(lanes), dtype=int)
    for j in succ[succ >= 0]:
        npred[j] += 1
    succ[(succ >= 0) & (npred[np.maximum(succ, 0)] != 1)] = -1
    has_pred = np.zeros(len(lanes), dtype=bool)
    has_pred[succ[succ >= 0]] = True
    used = np.zeros(len(lanes), dtype=bool)
    chains = []
    for head in [i for i in range(len(lanes)) if not has_pred[i]] + list(range(len(lanes))):
        if used[head]:
            continue                         # second pass: what is left are rings
        order = []
        k = head
        while k >= 0 and not used[k]:
            used[k] = True
            order.append(k)
            k = succ[k]
        chains.append(order)
    chains.sort(key=lambda c: c[0])
    out = []
    for order in chains:
        pts = [lanes[order[0]].points]
        lengths = [lanes[order[0]].length]
        for k in order[1:]:
            pts.append(lanes[k].points[1:])    # the shared joint point once
            lengths.append(lanes[k].length)
        first, last = lanes[order[0]].id, lanes[order[-1]].id
        name = first if len(order) == 1 else f"{first}..{last}"
        out.append(ChainedLane(name, np.concatenate(pts), tuple(lanes[k].id for k in order),
                               np.concatenate([[0.0], np.cumsum(lengths)[:-1]])))
    return out


def unit_vector(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to length 1 (a zero vector stays near zero instead of dividing by it)."""
    return v / max(float(np.linalg.norm(v)), 1e-12)


def project_to_lane(lane: Lane, xy: np.ndarray, chunk: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Arc length ``s`` of the closest lane point and signed lateral offset (left of travel
    positive) for plan points (N,2); exact on the polyline."""
    xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
    a, b = lane.points[:-1], lane.points[1:]
    ab = b - a
    ll = np.maximum((ab ** 2).sum(1), 1e-24)
    s_out, lat_out = np.empty(len(xy)), np.empty(len(xy))
    for i0 in range(0, len(xy), chunk):
        p = xy[i0:i0 + chunk]
        ap = p[:, None, :] - a[None]
        t = np.clip((ap * ab[None]).sum(-1) / ll[None], 0.0, 1.0)
        diff = ap - t[..., None] * ab[None]
        d2 = (diff ** 2).sum(-1)
        k = d2.argmin(1)
        rows = np.arange(len(p))
        s_out[i0:i0 + chunk] = lane.cum[k] + t[rows, k] * np.sqrt(ll[k])
        cross = ab[k, 0] * ap[rows, k, 1] - ab[k, 1] * ap[rows, k, 0]
        lat_out[i0:i0 + chunk] = np.sign(cross) * np.sqrt(d2[rows, k])
    return s_out, lat_out


def lane_ahead(lane: Lane, s: float, length_m: float = 80.0, behind_m: float = 5.0, step_m: float = 0.5) -> np.ndarray:
    """The lane centreline from ``behind_m`` before ``s`` to ``length_m`` after it (XY polyline,
    travel order) — what the ego-lane labeller needs for one frame."""
    a, b = max(0.0, s - behind_m), min(lane.length, s + length_m)
    return lane.at(np.linspace(a, b, max(2, int(math.ceil((b - a) / step_m)) + 1)))
