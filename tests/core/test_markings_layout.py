"""Lane markings as layout data: OpenDRIVE road marks -> LaneMarking curves -> USD and back.

References are independent of the code under test: the road-mark spans of CARLA Town01 are
summed straight from the XML (xml.etree) by the rule of the OpenDRIVE standard (a roadMark holds
from its sOffset to the next one's, or to the end of its lane section); the sample town's streets
are measured from the numbers its generator is built from (junction spacing, curve radius), and
each line's place is checked against the segment polygons it must border.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
import shapely
from pxr import Sdf, Usd, UsdGeom

from roadtwin_core import LaneMarking, RoadtwinError, TownLayout
from roadtwin_core.usd import read_layout, write_layout
from roadtwin_opendrive import load_network

REPO = Path(__file__).resolve().parents[2]
TOWN01 = REPO / "tests" / "data" / "opendrive" / "Town01.xodr"
STAGES = REPO / "stages"


@pytest.fixture(scope="module")
def town01():
    return load_network(TOWN01)


def _xml_spans(path: Path):
    """(road, junction?, lane id, type, colour, width, s length) of every roadMark span."""
    spans = []
    for road in ET.parse(path).getroot().iter("road"):
        length = float(road.get("length"))
        sections = road.findall("lanes/laneSection")
        starts = [float(ls.get("s")) for ls in sections] + [length]
        for k, ls in enumerate(sections):
            for lane in ls.iter("lane"):
                marks = sorted(lane.findall("roadMark"), key=lambda e: float(e.get("sOffset")))
                for j, rm in enumerate(marks):
                    a = starts[k] + float(rm.get("sOffset"))
                    b = starts[k] + float(marks[j + 1].get("sOffset")) if j + 1 < len(marks) else starts[k + 1]
                    color = rm.get("color") or "standard"
                    color = "white" if color == "standard" else color  # OpenDRIVE: standard = white
                    spans.append((road.get("id"), road.get("junction") != "-1", int(lane.get("id")),
                                  rm.get("type").replace(" ", "_"), color, float(rm.get("width") or 0), b - a))
    return spans


def test_town01_broken_yellow_centre_length_matches_the_xml(town01):
    want = sum(sp[6] for sp in _xml_spans(TOWN01) if sp[2] == 0 and sp[3] == "broken" and sp[4] == "yellow")
    got = sum(m.length_m for m in town01.layout.markings if m.marking_type == "broken" and m.color == "yellow")
    assert want > 2500  # CARLA Town01: ~2.9 km of broken yellow centre line
    assert got == pytest.approx(want, rel=0.02)


def test_town01_types_colours_widths_match_the_xml(town01):
    spans = [sp for sp in _xml_spans(TOWN01) if sp[3] != "none"]
    want_len: dict[tuple, float] = defaultdict(float)
    for sp in spans:
        want_len[(sp[3], sp[4], round(sp[5], 4))] += sp[6]
    # one curve per run of consecutive spans with one style on one lane (Town01: one section per road)
    runs = Counter()
    for road in ET.parse(TOWN01).getroot().iter("road"):
        for lane in road.iter("lane"):
            marks = sorted(lane.findall("roadMark"), key=lambda e: float(e.get("sOffset")))
            prev = None
            for rm in marks:
                key = (rm.get("type"), rm.get("color"), rm.get("width"))
                if rm.get("type") != "none" and key != prev:
                    runs[rm.get("type")] += 1
                prev = key
    got_len: dict[tuple, float] = defaultdict(float)
    for m in town01.layout.markings:
        got_len[(m.marking_type, m.color, round(m.width_m, 4))] += m.length_m
    assert set(got_len) == set(want_len) == {("broken", "yellow", 0.125), ("curb", "white", 0.1524)}
    for key, length in want_len.items():
        assert got_len[key] == pytest.approx(length, rel=0.02), key
    assert Counter(m.marking_type for m in town01.layout.markings) == runs
    broken = [m for m in town01.layout.markings if m.marking_type == "broken"]
    assert all((m.dash_m, m.gap_m) == (3.0, 9.0) for m in broken)  # no <type> lines in the file: MUTCD


def test_town01_markings_lie_on_lane_borders_in_travel_order(town01):
    """Outside junctions: each mark of lane n lies on that lane's outer border with the lane on
    the left of travel (the polyline runs in the lane's direction); centre lines lie on the
    border the two opposing driving lanes share."""
    lane_type, in_junction = {}, set()
    for road in ET.parse(TOWN01).getroot().iter("road"):  # Town01: one lane section per road
        if road.get("junction") != "-1":
            in_junction.add(road.get("id"))
        for lane in road.iter("lane"):
            lane_type[(road.get("id"), int(lane.get("id")))] = lane.get("type")
    segs = town01.layout.segments
    polys = [s.polygon() for s in segs]
    tree = shapely.STRtree(polys)
    checked = Counter()
    for m in town01.layout.markings:
        road, _, lane, _ = m.id[1:].split("_")
        lane_id = 0 if lane == "c0" else int(lane[2:]) * (-1 if lane[1] == "m" else 1)
        p = m.points
        mid = (len(p) - 1) // 2
        d = (p[mid + 1] - p[mid]) / np.linalg.norm(p[mid + 1] - p[mid])
        left = np.array([-d[1], d[0]])
        at = 0.5 * (p[mid] + p[mid + 1])
        kinds_l, kinds_r = ({segs[i].kind for i in tree.query(shapely.Point(at + sgn * 0.08 * left),
                                                               predicate="intersects")} for sgn in (1, -1))
        if road in in_junction:  # junction lanes are merged into overlapping surfaces: no sides to check
            continue
        if lane_id:
            own = lane_type[(road, lane_id)]
            assert own in kinds_l and own not in kinds_r, (m.id, kinds_l, kinds_r)
            checked["lane"] += 1
        else:
            assert kinds_l == kinds_r == {"driving"}, m.id
            q = shapely.Point(p[mid])
            assert min(polys[i].boundary.distance(q) for i in tree.query(q.buffer(0.01))) < 1e-6, m.id
            checked["centre"] += 1
    assert checked["lane"] >= 50 and checked["centre"] >= 20


# ---- layout USD I/O ------------------------------------------------------------------------

def _small_layout(markings):
    from roadtwin_core import RoadSegment
    seg = RoadSegment("road", "driving", np.array([[0, -3.5, 0], [20, -3.5, 0], [20, 3.5, 0], [0, 3.5, 0.0]]),
                      np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, -1.75], [20, -1.75]]))
    return TownLayout("Town", [seg], markings=markings)


def _all_kinds():
    rng = np.random.default_rng(3)
    out = []
    for i, kind in enumerate(("solid", "broken", "solid_solid", "solid_broken", "broken_solid", "broken_broken",
                              "botts_dots", "curb")):
        pts = np.cumsum(rng.uniform(0.5, 2.0, (5 + i, 2)), axis=0)
        broken = "broken" in kind or kind == "botts_dots"
        out.append(LaneMarking(f"m{i}-{kind}", kind, ("white", "yellow", "blue")[i % 3], 0.1 + 0.01 * i, pts,
                               dash_m=1.5 + i if broken else 0.0, gap_m=4.5 + i if broken else 0.0,
                               phase_m=0.25 * i, spacing_m=0.3 if "_" in kind and kind != "botts_dots" else 0.0))
    return out


def test_write_read_round_trip(tmp_path):
    marks = _all_kinds()
    path = write_layout(_small_layout(marks), tmp_path / "layout.usda")
    back = read_layout(path).markings
    assert len(back) == len(marks)
    for a, b in zip(marks, back):
        assert b.id == a.id.replace("-", "_")  # the prim name (safe id), as for segments
        assert (b.marking_type, b.color) == (a.marking_type, a.color)
        for name in ("width_m", "dash_m", "gap_m", "phase_m", "spacing_m"):
            assert getattr(b, name) == pytest.approx(getattr(a, name), abs=1e-12), name
        np.testing.assert_allclose(b.points, a.points, atol=1e-5)  # float32 points
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath("/Town/Markings/m3_solid_broken")
    curves = UsdGeom.BasisCurves(prim)
    assert prim.IsA(UsdGeom.BasisCurves) and curves.GetTypeAttr().Get() == "linear"
    assert curves.GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    assert list(curves.GetWidthsAttr().Get()) == pytest.approx([0.13])
    assert np.asarray(curves.GetPointsAttr().Get())[:, 2].tolist() == [0.0] * len(marks[3].points)
    assert prim.GetAttribute("roadtwin:marking:type").GetTypeName() == Sdf.ValueTypeNames.Token


def test_layout_without_markings_reads_empty(tmp_path):
    path = write_layout(_small_layout([]), tmp_path / "layout.usda")
    assert read_layout(path).markings == []
    assert not Usd.Stage.Open(str(path)).GetPrimAtPath("/Town/Markings")


@pytest.mark.parametrize("case, edit, message", [
    ("unknown_type", lambda p: p.GetAttribute("roadtwin:marking:type").Set("zigzag"), "unknown type 'zigzag'"),
    ("width_as_text", lambda p: (p.RemoveProperty("roadtwin:marking:widthM"),
                                 p.CreateAttribute("roadtwin:marking:widthM", Sdf.ValueTypeNames.String).Set("wide")),
     "roadtwin:marking:widthM must be a number"),
    ("no_width", lambda p: p.RemoveProperty("roadtwin:marking:widthM"), "needs roadtwin:marking:widthM"),
    ("zero_width", lambda p: p.GetAttribute("roadtwin:marking:widthM").Set(0.0), "width_m must be > 0"),
    ("one_point", lambda p: (UsdGeom.BasisCurves(p).GetPointsAttr().Set([(0, 0, 0)]),
                             UsdGeom.BasisCurves(p).GetCurveVertexCountsAttr().Set([1])), "at least 2 points"),
    ("two_curves", lambda p: UsdGeom.BasisCurves(p).GetCurveVertexCountsAttr().Set([2, 3]), "exactly one curve"),
    ("nan_point", lambda p: UsdGeom.BasisCurves(p).GetPointsAttr().Set(
        [(0, 0, 0), (float("nan"), 0, 0), (1, 1, 0), (2, 2, 0), (3, 3, 0)]), "NaN"),
])
def test_malformed_marking_names_the_prim(tmp_path, case, edit, message):
    path = write_layout(_small_layout(_all_kinds()[:1]), tmp_path / f"{case}.usda")
    stage = Usd.Stage.Open(str(path))
    edit(stage.GetPrimAtPath("/Town/Markings/m0_solid"))
    stage.Save()
    with pytest.raises(RoadtwinError) as exc:
        read_layout(path)
    text = str(exc.value)
    assert f"{case}.usda" in text and "/Town/Markings/m0_solid" in text and message in text, text
    assert "\n" not in text


# ---- sample layouts ------------------------------------------------------------------------

LANE = 3.5
STREETS = {  # name -> length between the junction squares (+-3.5 m), from the grid of make_town.py
    "street0_0": 150 - 2 * LANE, "street0_1": 150 - 2 * LANE, "street1_0": 150 - 2 * LANE,
    "street1_1": 150 - 2 * LANE, "avenue0": 120 - 2 * LANE, "avenue1": 120 - 2 * LANE, "avenue2": 120 - 2 * LANE,
    "north": 60 + math.pi / 2 * 40 + 80}


@pytest.fixture(scope="module")
def town():
    return read_layout(STAGES / "town.usda")


def test_sample_town_has_centre_and_edge_lines_per_street(town):
    by_id = {m.id: m for m in town.markings}
    assert len(by_id) == 3 * len(STREETS)
    for street, length in STREETS.items():
        centre = by_id[f"{street}_centre"]
        assert (centre.marking_type, centre.color, centre.dash_m > 0) == ("broken", "yellow", True)
        # the curve is sampled every <= 2.5 m, so its chords are within 0.2 % of the arc
        assert centre.length_m == pytest.approx(length, rel=0.002), street
        for side in ("left", "right"):
            edge = by_id[f"{street}_edge_{side}"]
            assert (edge.marking_type, edge.color, edge.dash_m) == ("solid", "white", 0.0)
            assert edge.length_m == pytest.approx(length, rel=0.03), street  # +-3.5 m around the curve


def _side_kinds(layout: TownLayout, m: LaneMarking, offset: float = 0.2):
    segs = layout.segments
    tree = shapely.STRtree([s.polygon() for s in segs])
    out = []
    for i in range(len(m.points) - 1):
        d = m.points[i + 1] - m.points[i]
        d /= np.linalg.norm(d)
        left = np.array([-d[1], d[0]])
        at = 0.5 * (m.points[i] + m.points[i + 1])
        out.append(tuple(frozenset(segs[j].kind for j in tree.query(shapely.Point(at + sgn * offset * left),
                                                                     predicate="intersects")) for sgn in (1, -1)))
    return set(out)


@pytest.mark.parametrize("stage", ["town.usda", "defect_avoidance.usda"])
def test_sample_lines_border_the_right_lanes(stage, town):
    """Centre lines run between two driving lanes, edge lines between the driving lane (left of
    travel) and the sidewalk; no marking enters a junction."""
    layout = town if stage == "town.usda" else read_layout(STAGES / stage)
    assert layout.markings
    drive, walk = frozenset({"driving"}), frozenset({"sidewalk"})
    # interior of the junction squares (the streets end on their boundary)
    inside = shapely.union_all([s.polygon() for s in layout.segments if s.kind == "junction"]).buffer(-1e-6)
    for m in layout.markings:
        want = {(drive, drive)} if "centre" in m.id else {(drive, walk)}
        assert _side_kinds(layout, m) == want, m.id
        assert not inside.intersects(shapely.LineString(m.points)), m.id


def test_defect_avoidance_lines_span_the_road():
    layout = read_layout(STAGES / "defect_avoidance.usda")
    by_id = {m.id: m for m in layout.markings}
    assert set(by_id) == {"centre", "edge_left", "edge_right"}
    for m, y in ((by_id["centre"], 0.0), (by_id["edge_right"], -LANE), (by_id["edge_left"], LANE)):
        assert m.length_m == pytest.approx(110.0)
        assert np.allclose(m.points[:, 1], y)
    assert by_id["edge_right"].points[0, 0] < by_id["edge_right"].points[-1, 0]  # right lane travels +x
