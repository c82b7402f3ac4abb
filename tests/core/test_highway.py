"""stages/highway.usda: cross-section, alignment limits, shared borders, markings and rules,
checked against the design numbers with geometry computed here (not the generator's helpers)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

STAGES = Path(__file__).resolve().parents[2] / "stages"


@pytest.fixture(scope="module")
def hw():
    sys.path.insert(0, str(STAGES))
    try:
        import make_highway
    finally:
        sys.path.remove(str(STAGES))
    return make_highway


@pytest.fixture(scope="module")
def layout(hw):
    return hw.build()


def _reference(layout) -> np.ndarray:
    """The road's reference line rebuilt from the right lane's centrelines (lane centre at
    -1.75 m): the left edge of each right-lane segment is the reference line itself."""
    lanes = sorted((s for s in layout.segments if s.id.endswith("lane_r")), key=lambda s: s.id)
    return np.concatenate([s.centerline if k == 0 else s.centerline[1:] for k, s in enumerate(lanes)])


def test_cross_section_lane_shoulder_verge_widths(layout):
    ref = LineString(_reference(layout))
    line = ref.offset_curve(1.75)              # the reference line (right lane centre + 1.75 left)
    kinds = {"driving": (0.0, 3.5), "shoulder": (3.5, 5.75), "verge": (5.75, 10.75)}
    for seg in layout.segments[:60] + layout.segments[-60:]:
        lo, hi = kinds[seg.kind]
        d = shapely.distance(shapely.points(seg.vertices[:, :2]), line)
        assert d.min() == pytest.approx(lo, abs=0.01) and d.max() == pytest.approx(hi, abs=0.01), seg.id
    counts = {k: sum(s.kind == k for s in layout.segments) for k in kinds}
    assert counts["driving"] == 2 * counts["shoulder"] / 2 == counts["verge"]
    lane = next(s for s in layout.segments if s.kind == "driving")
    area = abs(shapely.area(lane.polygon()))
    assert area / LineString(lane.centerline).length == pytest.approx(3.5, rel=1e-3)


def test_neighbouring_segments_share_border_vertices_exactly(layout):
    by_id = {s.id: s for s in layout.segments}
    pts = lambda sid: {tuple(p) for p in by_id[sid].vertices[:, :2]}  # noqa: E731
    for piece in (0, 17, 41):
        for strip in ("verge_r", "shoulder_r", "lane_r", "lane_l", "shoulder_l", "verge_l"):
            assert len(pts(f"hw_{piece:03d}_{strip}") & pts(f"hw_{piece + 1:03d}_{strip}")) == 2
        for a, b in (("verge_r", "shoulder_r"), ("shoulder_r", "lane_r"), ("lane_r", "lane_l"), ("lane_l", "shoulder_l")):
            assert len(pts(f"hw_{piece:03d}_{a}") & pts(f"hw_{piece:03d}_{b}")) == 11    # 25 m in 2.5 m steps


def test_alignment_curves_and_grades_are_rural_highway_like(layout):
    from roadtwin_core.surface import SampledSurface

    ref = LineString(_reference(layout)).offset_curve(1.75)
    length = ref.length
    assert 1500 <= length <= 2100
    p = np.asarray(ref.coords)[::2]                            # 5 m chords
    a, b, c = p[:-2], p[1:-1], p[2:]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    sides = np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - b, axis=1) * np.linalg.norm(c - a, axis=1)
    with np.errstate(divide="ignore"):
        radius = sides / (2 * np.abs(cross))
    assert radius.min() >= 300 * 0.98                           # curves of 320-1000 m
    assert (radius > 5000).mean() > 0.3                         # and straight tangents
    surf = SampledSurface(layout.terrain)
    s = np.arange(0, length, 10.0)
    z = surf.height(np.array([ref.interpolate(x).coords[0] for x in s]))
    grade = np.diff(z) / 10.0
    assert np.abs(grade).max() <= 0.041 and np.abs(grade).max() >= 0.035
    change = np.diff(grade)
    assert change.min() < -0.0005 and change.max() > 0.0005     # crest and sag curves
    # crowned at 2 % (the k-d tree's local plane fit rounds the ridge between samples by about
    # a centimetre): the crown is highest and the lane falls away at nearly the design crossfall
    s_mid = length / 2
    p0, p1 = (np.asarray(ref.interpolate(x).coords[0]) for x in (s_mid, s_mid + 1.0))
    right = np.array([p1[1] - p0[1], p0[0] - p1[0]]) / np.linalg.norm(p1 - p0)
    zl2, zl1, zc, zr1, zr2 = surf.height(np.array([p0 + o * right for o in (-2.6, -0.9, 0.0, 0.9, 2.6)]))
    assert zc > max(zl1, zr1)
    for near, far in ((zl1, zl2), (zr1, zr2)):
        assert 0.015 <= (near - far) / 1.7 <= 0.025


def test_markings_centre_and_edge_lines(layout):
    ref = LineString(_reference(layout)).offset_curve(1.75)
    centre = [m for m in layout.markings if m.color == "yellow"]
    edges = [m for m in layout.markings if m.color == "white"]
    assert sum(m.length_m for m in centre) == pytest.approx(ref.length, rel=1e-3)
    kinds = [m.marking_type for m in centre]
    assert kinds.count("solid_solid") == 2 and set(kinds) == {"broken", "solid_solid"}
    for m in centre:
        assert shapely.distance(shapely.points(m.points), ref).max() < 0.01
        if m.marking_type == "broken":
            assert (m.dash_m, m.gap_m) == (4.0, 12.0)
    assert len(edges) == 2 and all(m.marking_type == "solid" for m in edges)
    for m in edges:
        d = shapely.distance(shapely.points(m.points), ref)
        assert np.allclose(d, 3.5, atol=0.01)
    # each edge line runs in its lane's travel direction: the lane is on its left
    for m in edges:
        t = m.points[10] - m.points[9]
        to_ref = np.asarray(ref.interpolate(ref.project(shapely.Point(m.points[9]))).coords[0]) - m.points[9]
        assert t[0] * to_ref[1] - t[1] * to_ref[0] > 0


def test_rules_are_dense_and_favour_potholes_and_cracks(layout, hw):
    from roadtwin_core.town.placement import lane_length_km
    from roadtwin_core.usd import read_layout

    r = layout.rules
    w = r.type_weights
    assert w["pothole"] + w["crack"] > 0.7 * sum(w.values()) and "patch" in w
    assert "driving" in r.kinds
    per_lane_km = r.density_per_km * lane_length_km(layout.segments, r.kinds)
    driving_share = 3.5 / (3.5 + 2.25) if "shoulder" in r.kinds else 1.0
    assert 150 <= per_lane_km * driving_share / lane_length_km(layout.segments, ("driving",)) <= 400
    stored = read_layout(STAGES / "highway.usda")               # the shipped file is up to date
    assert len(stored.segments) == len(layout.segments)
    assert stored.rules.type_weights == w and stored.rules.density_per_km == r.density_per_km


@pytest.mark.slow
def test_highway_composes_in_about_a_minute(tmp_path, layout):
    """Compose with the types this checkout has (patch lands with the looks work). Measured in
    CPU seconds of one serial process, so a busy machine does not fail it (about 50 s on two
    idle cores with the process pool, wall clock)."""
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.plugins import get_plugin_manager
    from roadtwin_core.usd import write_layout

    known = get_plugin_manager().registry("defect_types")
    layout.rules.type_weights = {t: v for t, v in layout.rules.type_weights.items() if t in known}
    path = write_layout(layout, tmp_path / "highway.usda")
    t0 = time.process_time()
    result = compose(path, tmp_path / "out", preview=False, executor="serial")
    elapsed = time.process_time() - t0
    assert elapsed < 90, elapsed
    summary = result.summary if hasattr(result, "summary") else result
    assert summary["validation"]["errors"] == 0
    assert summary["defects"] >= 1500
    assert summary["defects_by_type"]["pothole"] + summary["defects_by_type"]["crack"] > 0.7 * summary["defects"]
