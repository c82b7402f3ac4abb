"""Generate stages/highway.usda: a two-lane rural highway built for perception data.

Modelled on the Brazilian federal highways of the real survey frames (road_defects_br): one
3.5 m lane each way (right-hand traffic), paved shoulders of 2.25 m, then a 5 m verge (grass or
gravel later, kind ``verge``) on each side. About 2.0 km long: straight tangents joined by
circular curves of 320-1000 m radius through 60 m clothoids (curvature ramps linearly, as road
design does, so a camera driving the lane never sees a kink); grades of up to 4 % joined by
parabolic crest and sag curves (grade ramps linearly over 250 m). The cross-section has a 2 %
crown on the lanes, 3 % on the shoulders and 6 % down the verges.

Markings (``TownLayout.markings``): a broken yellow centre line (4 m dash, 12 m gap, the
Brazilian LFO pattern for roads above 80 km/h) except in two no-passing zones (the sharpest
curve and the last crest) with a double solid yellow line, and solid white edge lines between
lane and shoulder.

Defects are dense so that most views contain some: ``densityPerKm`` counts per km of lane
centreline (4.0 km here); shoulders take defects too (about 40 % of the allowed area), so a
density of 560 puts about 340 per km into each lane. Type weights favour potholes and cracks,
with ``patch`` (repaired asphalt, the commonest false positive) — a type the looks work adds:
composing this layout needs that plugin.

Segments are cut every 25 m, neighbours share their border vertices exactly. Terrain samples
follow the road corridor (every 2.5 m along, on the cross-section's break lines).
Run: ``python stages/make_highway.py`` (output is deterministic).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import triangle

from roadtwin_core import ComposeRules, LaneMarking, RoadSegment, TownLayout
from roadtwin_core.usd import write_layout

LANE, SHOULDER, VERGE, SPLIT = 3.5, 2.25, 5.0, 25.0
STEP = 2.5                      # centreline sample spacing (m)
CLOTHOID = 60.0                 # curvature ramp length (m)
VERTICAL_CURVE = 250.0          # grade ramp length at each grade change (m)
CROSSFALL = {"lane": 0.02, "shoulder": 0.03, "verge": 0.06}
# (tangent length before the curve, radius (+ left, - right), curve deflection in degrees)
CURVES = [(200.0, 700.0, 18.0), (180.0, -400.0, 28.0), (250.0, 1000.0, 12.0), (150.0, 320.0, 22.0)]
FINAL_TANGENT = 230.0
# Grade change points (s, grade after it); grades stay within +-4 %.
GRADES = [(0.0, 0.03), (420.0, -0.025), (900.0, 0.04), (1330.0, -0.016)]
CENTRE_DASH, CENTRE_GAP = 4.0, 12.0
# No-passing zones (s ranges) get a double solid centre line: the 400 m curve and the last crest.
NO_PASSING = [(380.0, 700.0), (1200.0, 1460.0)]
TYPE_WEIGHTS = {"pothole": 5.0, "crack": 4.0, "patch": 2.0, "depression": 0.5, "rut": 0.5}
DENSITY_PER_KM = 250.0  # about half of survey views see a pothole or crack 5-25 m ahead, as in the real frames

# Strip layout across the road: lateral offsets (left of the reference line positive) and kinds.
OFFSETS = [-(LANE + SHOULDER + VERGE), -(LANE + SHOULDER), -LANE, 0.0, LANE, LANE + SHOULDER,
           LANE + SHOULDER + VERGE]
KINDS = ["verge", "shoulder", "driving", "driving", "shoulder", "verge"]
NAMES = ["verge_r", "shoulder_r", "lane_r", "lane_l", "shoulder_l", "verge_l"]


def curvature_profile(s: np.ndarray) -> np.ndarray:
    """Plan curvature (1/m) along the reference line: tangents, clothoid ramps, arcs."""
    k = np.zeros_like(s)
    start = 0.0
    for tangent, radius, deflection in CURVES:
        start += tangent
        arc = abs(radius) * np.radians(deflection) - CLOTHOID   # deflection = arc + 2 half-clothoids
        ramp_up = np.clip((s - start) / CLOTHOID, 0, 1)
        ramp_down = np.clip((start + CLOTHOID + arc + CLOTHOID - s) / CLOTHOID, 0, 1)
        k += np.minimum(ramp_up, ramp_down) / radius
        start += 2 * CLOTHOID + arc
    return k


def total_length() -> float:
    return sum(t + abs(r) * np.radians(d) + CLOTHOID for t, r, d in CURVES) + FINAL_TANGENT


def grade_profile(s: np.ndarray) -> np.ndarray:
    """Longitudinal grade along s: constant grades with linear ramps (parabolic vertical curves)."""
    g = np.full_like(s, GRADES[0][1])
    for (s0, g0), (s1, g1) in zip(GRADES[:-1], GRADES[1:]):
        g += (g1 - g0) * np.clip((s - s1 + VERTICAL_CURVE / 2) / VERTICAL_CURVE, 0, 1)
    return g


def alignment(step: float = STEP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference line XY (N,2), its arc length s (N,) and elevation z (N,), sampled every ``step``
    m, integrated from curvature and grade on a 0.25 m grid (trapezoid rule)."""
    length = total_length()
    fine = np.linspace(0.0, length, int(round(length / 0.25)) + 1)
    ds = np.diff(fine)
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature_profile(fine[1:]) + curvature_profile(fine[:-1])) * ds)])
    x = np.concatenate([[0.0], np.cumsum(0.5 * (np.cos(heading[1:]) + np.cos(heading[:-1])) * ds)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (np.sin(heading[1:]) + np.sin(heading[:-1])) * ds)])
    z = np.concatenate([[0.0], np.cumsum(0.5 * (grade_profile(fine[1:]) + grade_profile(fine[:-1])) * ds)])
    s = np.linspace(0.0, length, int(round(length / step)) + 1)
    return np.column_stack([np.interp(s, fine, x), np.interp(s, fine, y)]), s, np.interp(s, fine, z)


def left_normals(center: np.ndarray) -> np.ndarray:
    d = np.gradient(center, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.column_stack([-d[:, 1], d[:, 0]])


def cross_section(offset: np.ndarray) -> np.ndarray:
    """Height relative to the crown at a lateral offset (crowned lanes, steeper shoulders, verges)."""
    a = np.abs(offset)
    lane = np.minimum(a, LANE)
    shoulder = np.clip(a - LANE, 0, SHOULDER)
    verge = np.clip(a - LANE - SHOULDER, 0, None)
    return -(CROSSFALL["lane"] * lane + CROSSFALL["shoulder"] * shoulder + CROSSFALL["verge"] * verge)


def _mesh(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(poly)
    t = triangle.triangulate({"vertices": poly, "segments": np.column_stack([np.arange(n), (np.arange(n) + 1) % n])}, "p")
    return t["vertices"], t["triangles"]


def segments(center: np.ndarray, s: np.ndarray) -> list[RoadSegment]:
    """Strips between the OFFSETS lines, cut every SPLIT m. Driving strips carry their lane's
    centreline in travel order (right of the reference line: along it; left: against it)."""
    normal = left_normals(center)
    edges = [center + o * normal for o in OFFSETS]
    cuts = np.unique(np.concatenate([[0], np.searchsorted(s, np.arange(SPLIT, s[-1] - 1e-6, SPLIT)), [len(s) - 1]]))
    out = []
    for piece, (i0, i1) in enumerate(zip(cuts[:-1], cuts[1:])):
        for k, (kind, name) in enumerate(zip(KINDS, NAMES)):
            lo, hi = edges[k][i0:i1 + 1], edges[k + 1][i0:i1 + 1]
            v, f = _mesh(np.concatenate([lo, hi[::-1]]))
            mid = 0.5 * (lo + hi)
            line = None
            if kind == "driving":
                line = mid if OFFSETS[k] + OFFSETS[k + 1] < 0 else mid[::-1]
            out.append(RoadSegment(f"hw_{piece:03d}_{name}", kind, v, f, line, {"road": "highway"}))
    return out


def _sub_polyline(line: np.ndarray, s: np.ndarray, a: float, b: float) -> np.ndarray:
    """The part of ``line`` (sampled at arc lengths ``s``) between a and b, endpoints interpolated."""
    inner = (s > a) & (s < b)
    ends = [np.array([[np.interp(t, s, line[:, 0]), np.interp(t, s, line[:, 1])]]) for t in (a, b)]
    return np.concatenate([ends[0], line[inner], ends[1]])


def markings(center: np.ndarray, s: np.ndarray) -> list[LaneMarking]:
    """Centre line (broken yellow, double solid yellow in no-passing zones) and white edge lines.
    Centre-line points run along the reference line; each edge line in its own lane's travel
    order. Broken zones keep one dash pattern along the whole road (phase from s)."""
    period = CENTRE_DASH + CENTRE_GAP
    bounds = [0.0] + [x for zone in NO_PASSING for x in zone] + [float(s[-1])]
    out = []
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        pts = _sub_polyline(center, s, a, b)
        if k % 2:
            out.append(LaneMarking(f"centre_{k:02d}", "solid_solid", "yellow", 0.12, pts, spacing_m=0.25))
        else:
            out.append(LaneMarking(f"centre_{k:02d}", "broken", "yellow", 0.12, pts, dash_m=CENTRE_DASH,
                                   gap_m=CENTRE_GAP, phase_m=float((-a) % period)))
    normal = left_normals(center)
    out.append(LaneMarking("edge_r", "solid", "white", 0.15, center - LANE * normal))
    out.append(LaneMarking("edge_l", "solid", "white", 0.15, (center + LANE * normal)[::-1]))
    return out


def terrain(center: np.ndarray, s: np.ndarray, z: np.ndarray, every: float = 2.5) -> np.ndarray:
    """Elevation samples across the corridor on the cross-section's break lines (crown, lane
    edges, shoulder edges, verge middle and edges), every ``every`` m along. Spacing along and
    across is similar on purpose: the k-d tree surface fits a plane to the 8 nearest samples,
    which must not all lie on one cross line."""
    outer = LANE + SHOULDER + VERGE
    half_lateral = np.array([0.0, LANE / 4, LANE / 2, 3 * LANE / 4, LANE, LANE + SHOULDER / 2, LANE + SHOULDER,
                             LANE + SHOULDER + VERGE / 2, outer, outer + 3.0])
    lateral = np.unique(np.concatenate([-half_lateral, half_lateral]))
    si = np.arange(0.0, s[-1] + 1e-9, every)
    c = np.column_stack([np.interp(si, s, center[:, 0]), np.interp(si, s, center[:, 1])])
    n = left_normals(c)
    zc = np.interp(si, s, z)
    xy = c[:, None, :] + lateral[None, :, None] * n[:, None, :]
    zz = zc[:, None] + cross_section(lateral)[None, :]
    return np.column_stack([xy.reshape(-1, 2), zz.ravel()])


def build(type_weights: dict[str, float] | None = None) -> TownLayout:
    center, s, z = alignment()
    rules = ComposeRules(defect_count=0, density_per_km=DENSITY_PER_KM, seed=11, surface="iso8608:B:0.2",
                         merger="cdt", kinds=("driving", "shoulder"), models_per_type=6,
                         type_weights=dict(type_weights or TYPE_WEIGHTS), edge_margin_m=0.15, spacing_m=0.3)
    layout = TownLayout("Highway", segments(center, s), rules, terrain=terrain(center, s, z),
                        metadata={"roadClass": "two-lane rural highway (federal, Brazil-like)",
                                  "laneWidthM": str(LANE), "shoulderWidthM": str(SHOULDER)})
    layout.markings = markings(center, s)
    return layout


if __name__ == "__main__":
    out = Path(__file__).with_name("highway.usda")
    write_layout(build(), out, "roadtwin sample highway: two-lane rural road, shoulders, verges, dense defects "
                               "(synthetic, CC0)")
    print(f"wrote {out}")
