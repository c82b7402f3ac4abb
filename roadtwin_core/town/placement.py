"""Seeded, lane-aware, non-overlapping defect placement (paper step 1).

Defects go on segments of the allowed kinds (driving lanes by default), uniformly by area; each
footprint must stay ``edge_margin_m`` inside the allowed road area and ``spacing_m`` away from
every other defect. Crossing a border *between* allowed segments is fine: the merger clips
the defect into both. Ruts and bumps (and any type that says ``along_travel``, e.g. tyre marks)
follow the lane's travel direction; other types get a random yaw.
"""
from __future__ import annotations

from typing import Collection

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.strtree import STRtree

from ..errors import RoadtwinError
from ..model import ComposeRules, DefectModel, Placement, RoadSegment, triangle_areas

ALONG_TRAVEL = {"rut", "bump"}   # place_defects' default; compose adds every registered type whose along_travel is True
MAX_TRIES = 400
WHEEL_PATH_OFFSET_M = 0.85   # half the track of a passenger car: wheel paths sit this far off the lane centre
WHEEL_PATH_HALF_WIDTH_M = 0.35


def lane_length_km(segments: list[RoadSegment], kinds: tuple[str, ...]) -> float:
    """Total centerline length of the lanes defects may go on (for densities per km of lane)."""
    total = 0.0
    for s in segments:
        if s.kind in kinds and s.centerline is not None and len(s.centerline) > 1:
            total += float(np.linalg.norm(np.diff(s.centerline, axis=0), axis=1).sum())
    return total / 1000.0


def _wheel_path_acceptance(seg: RoadSegment, xy: np.ndarray, weight: float, lines: dict) -> float:
    """Rejection-sampling weight: 1 in a wheel path, 1/weight elsewhere (and off-centerline lanes)."""
    if weight <= 1.0 or seg.centerline is None or len(seg.centerline) < 2:
        return 1.0 / max(weight, 1.0)
    if seg.id not in lines:
        lines[seg.id] = LineString(seg.centerline)
    d = lines[seg.id].distance(Point(xy))
    return 1.0 if abs(d - WHEEL_PATH_OFFSET_M) <= WHEEL_PATH_HALF_WIDTH_M else 1.0 / weight


def _covers_area(segment_poly: Polygon, footprint: Polygon) -> bool:
    """Does the footprint overlap the segment by more than a sliver? A segment that contains it
    (most defects sit inside one segment) needs no intersection to say so."""
    if footprint.area > 1e-9 and segment_poly.contains(footprint):
        return True
    return segment_poly.intersection(footprint).area > 1e-9


def place_defects(segments: list[RoadSegment], library: dict[str, list[DefectModel]], rules: ComposeRules,
                  rng: np.random.Generator, owner: str, fixed: list[Placement] = (),
                  along_travel: Collection[str] = ALONG_TRAVEL) -> list[Placement]:
    """Fixed placements first (checked, never moved), then ``rules.defect_count`` random ones.
    ``along_travel``: types yawed with the lane's direction (the rest get a uniform yaw)."""
    if rules.defect_count == 0 and not fixed:
        return []
    allowed = [s for s in segments if s.kind in rules.kinds]
    if not allowed:
        raise RoadtwinError(f"{owner}: no road segments of kind {', '.join(rules.kinds)} to place defects on")
    road = _Road(allowed, rules)
    for p in fixed:
        why = road.try_add(p)
        if why:
            raise RoadtwinError(f"{owner}: fixed defect {p.instance_id!r} cannot be placed: {why}")
    if rules.defect_count == 0:
        return road.placed

    draw_type = _type_drawer(library, rules, rng, owner)
    lines: dict[str, LineString] = {}
    for i in range(rules.defect_count):
        t = draw_type()
        for attempt in range(MAX_TRIES):
            # A fresh model each try; past half the budget a fresh type too: on a crowded road the
            # big types (a speed bump spans the road) run out of room first, and the summary's
            # per-type counts show the resulting mix.
            if attempt >= MAX_TRIES // 2:
                t = draw_type()
            p = _draw_placement(f"D{i:05d}", t, library, road, rules, rng, lines, along_travel)
            if p is not None and not road.try_add(p, quick=True):
                break
        else:
            raise RoadtwinError(
                f"{owner}: only {len(road.placed) - len(fixed)} of {rules.defect_count} defects fit on the "
                f"{', '.join(rules.kinds)} road with spacing {rules.spacing_m} m; ask for fewer defects")
    return road.placed


class _Road:
    """The allowed road and the defects placed on it so far: where a footprint may go (inside
    the road by the edge margin, apart from the others by the spacing), and uniform random points
    on it (area-weighted triangle sampling)."""

    CELL = 4.0   # m, the grid that finds a new footprint's placed neighbours

    def __init__(self, allowed: list[RoadSegment], rules: ComposeRules):
        self.allowed, self.rules = allowed, rules
        self.polys = [s.polygon() for s in allowed]
        shapely.prepare(self.polys)   # contains() per accepted defect below; same answers, faster
        self.area_ok = shapely.union_all(self.polys).buffer(-rules.edge_margin_m)
        shapely.prepare(self.area_ok)
        self.tree = STRtree(self.polys)
        # Area-weighted triangle sampling gives uniform positions over the allowed road.
        self.tris = np.concatenate([s.vertices[s.faces][:, :, :2] for s in allowed])
        self.tseg = np.concatenate([np.full(len(s.faces), k) for k, s in enumerate(allowed)])
        w = np.abs(np.concatenate([triangle_areas(s.vertices, s.faces) for s in allowed]))
        self.cdf = np.cumsum(w) / w.sum()
        self.placed: list[Placement] = []
        self.grown: list[Polygon] = []
        self.grid: dict[tuple[int, int], list[int]] = {}

    def sample_point(self, rng: np.random.Generator) -> tuple[RoadSegment, np.ndarray]:
        k = int(np.searchsorted(self.cdf, rng.random()))
        a, b, c = self.tris[k]
        r1, r2 = rng.random(2)
        s1 = np.sqrt(r1)
        xy = (1 - s1) * a + s1 * (1 - r2) * b + s1 * r2 * c
        return self.allowed[self.tseg[k]], xy

    def try_add(self, p: Placement, quick: bool = False) -> str:
        """Why ``p`` cannot go where it is ("" when it was added). ``quick``: only whether (the
        reason given for a clash may name another defect than the first the grown footprint meets)."""
        rules, cell, grid = self.rules, self.CELL, self.grid
        fp = Polygon(p.world_footprint())
        if not fp.is_valid:
            return "its footprint self-intersects"
        if not self.area_ok.contains(fp):
            return f"it is not {rules.edge_margin_m} m inside the {', '.join(rules.kinds)} road"
        # Grid cells from the footprint's box grown by the buffer distance (it holds the buffer):
        # the same neighbours as the buffer's own box could meet, found before buffering.
        d = rules.spacing_m / 2
        x0, y0, x1, y1 = fp.bounds
        keys = [(gx, gy) for gx in range(int((x0 - d) // cell), int((x1 + d) // cell) + 1)
                for gy in range(int((y0 - d) // cell), int((y1 + d) // cell) + 1)]
        near = sorted({j for key in keys for j in grid.get(key, ())})
        if quick and any(fp.intersects(self.grown[j]) for j in near):
            return "it overlaps a placed defect"   # the buffer holds fp: no need to build it
        g = fp.buffer(d, quad_segs=2)
        clash = next((j for j in near if g.intersects(self.grown[j])), None)
        if clash is not None:
            return f"it overlaps defect {self.placed[clash].instance_id}"
        hit = self.tree.query(fp, predicate="intersects")
        p.segment_ids = tuple(sorted(self.allowed[j].id for j in hit if _covers_area(self.polys[j], fp)))
        for key in keys:
            grid.setdefault(key, []).append(len(self.placed))
        self.placed.append(p)
        self.grown.append(g)
        return ""


def _type_drawer(library: dict[str, list[DefectModel]], rules: ComposeRules, rng: np.random.Generator,
                 owner: str):
    """A function drawing a defect type by the rules' weights (types without models left out)."""
    types = sorted(t for t, wt in rules.type_weights.items() if wt > 0 and library.get(t))
    if not types:
        raise RoadtwinError(f"{owner}: no defect models for the weighted types {sorted(rules.type_weights)}")
    tw = np.array([rules.type_weights[t] for t in types], dtype=np.float64)
    tw /= tw.sum()
    # rng.choice(len(types), p=tw) without its per-call argument checks (~12 us, tens of
    # thousands of calls at 10,000 defects): numpy draws exactly this, one random() per call.
    type_cdf = tw.cumsum()
    type_cdf /= type_cdf[-1]

    def draw_type() -> str:
        return types[int(type_cdf.searchsorted(rng.random(), side="right"))]

    return draw_type


def _draw_placement(instance_id: str, t: str, library: dict[str, list[DefectModel]], road: _Road,
                    rules: ComposeRules, rng: np.random.Generator, lines: dict,
                    along_travel: Collection[str] = ALONG_TRAVEL) -> Placement | None:
    """One random try: a model of type ``t`` at a uniform point of the road, with its yaw and
    scale; None when the wheel-path weighting rejects the point."""
    model = library[t][rng.integers(len(library[t]))]
    seg, xy = road.sample_point(rng)
    if rng.random() > _wheel_path_acceptance(seg, xy, rules.wheel_path_weight, lines):
        return None
    if t in along_travel:
        d = seg.travel_direction(xy)[0]
        yaw = float(np.arctan2(d[1], d[0]) + rng.normal(0.0, np.radians(3.0)))
    else:
        yaw = float(rng.uniform(0, 2 * np.pi))
    s = float(rng.uniform(*rules.scale_range))
    return Placement(instance_id, model, float(xy[0]), float(xy[1]), yaw, (s, s, s))
