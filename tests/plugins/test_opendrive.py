"""The OpenDRIVE layout importer (plugins/roadtwin_opendrive).

Reference-line evaluation is checked against closed forms and against an independent numerical
integration (scipy.integrate.quad); lane geometry against the width polynomials read straight
from the XML; Town01's driving area against an independent integral of the lane strips
(xml.etree + quad here, none of the plugin's code). Maps: tests/data/opendrive (see README.md
and the licenses there).
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import shapely
from scipy.integrate import quad

from roadtwin_core import RoadtwinError, get_plugin_manager
from roadtwin_opendrive import (OpenDriveImporter, OpenDriveParams, ReferenceLine, geometry_xyh, load_network,
                                read_xodr)
from roadtwin_opendrive._xodr import Geometry

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "opendrive"
TOWN01 = DATA / "Town01.xodr"
CURVED = DATA / "curved_road_default.xodr"
CROSS = DATA / "intersection_3_5m_width.xodr"


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    return subprocess.run([sys.executable, "-m", "roadtwin_core.cli", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def town01():
    return load_network(TOWN01)


# ---- reference line ----------------------------------------------------------------------------

def _geom(kind, length, x=3.0, y=-2.0, hdg=0.7, **params):
    return Geometry(0.0, x, y, hdg, length, kind, params)


def test_line_closed_form():
    g = _geom("line", 12.0)
    x, y, h = geometry_xyh(g, np.array([0.0, 5.0, 12.0]))
    assert np.allclose(x, 3.0 + np.cos(0.7) * np.array([0, 5, 12]), atol=1e-12)
    assert np.allclose(y, -2.0 + np.sin(0.7) * np.array([0, 5, 12]), atol=1e-12)
    assert np.allclose(h, 0.7)


@pytest.mark.parametrize("k", [0.05, -0.12, 1e-9])
def test_arc_is_a_circle(k):
    length = 30.0
    g = _geom("arc", length, curvature=k)
    s = np.linspace(0, length, 61)
    x, y, h = geometry_xyh(g, s)
    assert np.allclose(h, 0.7 + k * s, atol=1e-12)
    if abs(k) > 1e-6:
        r = 1.0 / k
        cx, cy = 3.0 - r * math.sin(0.7), -2.0 + r * math.cos(0.7)  # centre on the left for k > 0
        assert np.allclose(np.hypot(x - cx, y - cy), abs(r), atol=1e-9)
        end = (cx + r * math.sin(0.7 + k * length), cy - r * math.cos(0.7 + k * length))
        assert np.allclose((x[-1], y[-1]), end, atol=1e-9)
    else:  # practically straight
        assert np.allclose((x[-1], y[-1]), (3 + length * math.cos(0.7), -2 + length * math.sin(0.7)), atol=1e-6)


@pytest.mark.parametrize("k0,k1,length", [(0.0, 0.08, 40.0), (0.05, -0.08, 35.0), (-0.2, -0.01, 30.0),
                                          (0.0, -0.3, 15.0), (0.1, 0.1 + 1e-7, 80.0), (-0.02, 0.0, 100.0)])
def test_clothoid_against_numerical_integration(k0, k1, length):
    x0, y0, h0 = 10.0, -4.0, -2.3
    g = _geom("spiral", length, x0, y0, h0, curvStart=k0, curvEnd=k1)

    def theta(s):
        return h0 + k0 * s + (k1 - k0) / (2 * length) * s * s

    for s_end in (length / 3, length):
        xr = x0 + quad(lambda s: math.cos(theta(s)), 0, s_end, epsabs=1e-12, epsrel=1e-12, limit=200)[0]
        yr = y0 + quad(lambda s: math.sin(theta(s)), 0, s_end, epsabs=1e-12, epsrel=1e-12, limit=200)[0]
        x, y, h = geometry_xyh(g, np.array([s_end]))
        assert abs(x[0] - xr) < 1e-9 and abs(y[0] - yr) < 1e-9
    assert math.isclose(h[0], h0 + 0.5 * (k0 + k1) * length, abs_tol=1e-12)
    x, y, h = geometry_xyh(g, np.array([0.0]))
    assert (x[0], y[0], h[0]) == pytest.approx((x0, y0, h0), abs=1e-12)


@pytest.mark.parametrize("p_range,b_u", [("normalized", 25.0), ("arcLength", 1.0)])
def test_param_poly3_straight_line(p_range, b_u):
    g = _geom("paramPoly3", 25.0, pRange=p_range, aU=0.0, bU=b_u, cU=0.0, dU=0.0, aV=0.0, bV=0.0, cV=0.0, dV=0.0)
    s = np.linspace(0, 25, 11)
    x, y, h = geometry_xyh(g, s)
    assert np.allclose(x, 3 + s * math.cos(0.7), atol=1e-12) and np.allclose(y, -2 + s * math.sin(0.7), atol=1e-12)
    assert np.allclose(h, 0.7)


def test_param_poly3_curve_follows_its_polynomials():
    g = _geom("paramPoly3", 20.0, 0.0, 0.0, 0.0, pRange="normalized",
              aU=0.0, bU=20.0, cU=-1.0, dU=0.5, aV=0.0, bV=0.0, cV=2.0, dV=-1.0)
    s = np.linspace(0, 20, 9)
    p = s / 20
    x, y, h = geometry_xyh(g, s)
    assert np.allclose(x, 20 * p - p ** 2 + 0.5 * p ** 3) and np.allclose(y, 2 * p ** 2 - p ** 3)
    assert np.allclose(h, np.arctan2(4 * p - 3 * p ** 2, 20 - 2 * p + 1.5 * p ** 2))


@pytest.mark.parametrize("kind,params,length", [
    ("arc", {"curvature": 0.07}, 30.0),
    ("spiral", {"curvStart": -0.05, "curvEnd": 0.09}, 45.0),
    ("poly3", {"a": 0.0, "b": 0.1, "c": 0.01, "d": -3e-4}, 30.0),
    ("paramPoly3", {"pRange": "arcLength", "aU": 0.0, "bU": 1.0, "cU": 0.0, "dU": 0.0,
                    "aV": 0.0, "bV": 0.0, "cV": 0.0, "dV": 0.0}, 12.0),
])
def test_sampled_arc_length_matches_geometry_length(kind, params, length):
    g = _geom(kind, length, **params)
    x, y, _ = geometry_xyh(g, np.linspace(0, length, 4001))
    assert math.isclose(np.hypot(np.diff(x), np.diff(y)).sum(), length, rel_tol=1e-6)


def test_poly3_is_its_cubic_in_the_local_frame():
    a, b, c, d = 0.0, 0.1, 0.01, -3e-4
    g = _geom("poly3", 30.0, 0.0, 0.0, 0.0, a=a, b=b, c=c, d=d)
    x, y, h = geometry_xyh(g, np.linspace(0, 30, 31))
    assert np.allclose(y, a + b * x + c * x ** 2 + d * x ** 3, atol=1e-12)
    assert np.allclose(np.tan(h), b + 2 * c * x + 3 * d * x ** 2, atol=1e-12)


def test_town01_geometries_join_up():
    """Each geometry's end is the next one's declared start (sign errors would show in meters)."""
    odr = read_xodr(TOWN01)
    gaps = []
    for road in odr.roads:
        for g0, g1 in zip(road.geometries[:-1], road.geometries[1:]):
            x, y, _ = geometry_xyh(g0, np.array([g1.s - g0.s]))
            gaps.append(math.hypot(x[0] - g1.x, y[0] - g1.y))
    assert max(gaps) < 1e-3  # the file stores coordinates to about float32 precision


# ---- a synthetic map with every feature ------------------------------------------------------

SYNTH = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="6" name="synth" vendor="tests">
  <geoReference><![CDATA[+proj=tmerc +lat_0=1 +lon_0=2]]></geoReference></header>
  <road id="7" length="80" junction="-1"><planView>{geoms}</planView>
    <elevationProfile><elevation s="0" a="1" b="0.02" c="0" d="0"/>
                      <elevation s="40" a="1.8" b="0.02" c="1e-4" d="0"/></elevationProfile>
    <lateralProfile><superelevation s="0" a="0.02" b="0" c="0" d="0"/>
                    <superelevation s="50" a="0.02" b="-0.001" c="0" d="0"/></lateralProfile>
    <lanes><laneOffset s="0" a="0.2" b="0.01" c="0" d="0"/>
      <laneSection s="0">
        <left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0.02" c="-5e-4" d="1e-6"/></lane>
              <lane id="2" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></left>
        <center><lane id="0" type="none"/></center>
        <right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
               <lane id="-2" type="shoulder"><width sOffset="0" a="0.5" b="-0.0125" c="0" d="0"/></lane>
               <lane id="-3" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></right>
      </laneSection>
      <laneSection s="40">
        <left><lane id="1" type="driving"><width sOffset="0" a="3.564" b="0" c="0" d="0"/></lane>
              <lane id="2" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></left>
        <right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
               <lane id="-2" type="parking"><width sOffset="0" a="0" b="0.2" c="-0.01" d="0"/>
                                            <width sOffset="25" a="0" b="0.1" c="0" d="0"/></lane>
               <lane id="-3" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></right>
      </laneSection></lanes></road>
</OpenDRIVE>"""


def _synth_geoms() -> list[Geometry]:
    """line, spiral, arc, paramPoly3, poly3, each starting where the previous ends."""
    specs = [("line", 10.0, {}), ("spiral", 20.0, {"curvStart": 0.0, "curvEnd": 0.05}),
             ("arc", 15.0, {"curvature": 0.05}),
             ("paramPoly3", 20.0, {"pRange": "normalized", "aU": 0.0, "bU": 20.0, "cU": 0.0, "dU": 0.0,
                                   "aV": 0.0, "bV": 0.0, "cV": 2.0, "dV": -1.0}),
             ("poly3", 15.0, {"a": 0.0, "b": 0.0, "c": 0.005, "d": 0.0})]
    out, s, x, y, h = [], 0.0, 0.0, 0.0, 0.3
    for kind, length, params in specs:
        g = Geometry(s, x, y, h, length, kind, params)
        out.append(g)
        xe, ye, he = geometry_xyh(g, np.array([length]))
        s, x, y, h = s + length, xe[0], ye[0], he[0]
    return out


def _synth_xml() -> str:
    parts = []
    for g in _synth_geoms():
        attrs = " ".join(f'{k}="{v!r}"' if isinstance(v, float) else f'{k}="{v}"' for k, v in g.params.items())
        parts.append(f'<geometry s="{float(g.s)!r}" x="{float(g.x)!r}" y="{float(g.y)!r}" hdg="{float(g.hdg)!r}" '
                     f'length="{float(g.length)!r}">'
                     f'<{g.kind} {attrs}/></geometry>')
    return SYNTH.format(geoms="".join(parts))


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    path = tmp_path_factory.mktemp("odr") / "synth.xodr"
    path.write_text(_synth_xml())
    return path, load_network(path)


def _cubic(records, s):
    """Independent piecewise cubic: records [(start, a, b, c, d)] sorted by start."""
    r = [q for q in records if q[0] <= s + 1e-12][-1]
    ds = s - r[0]
    return r[1] + r[2] * ds + r[3] * ds ** 2 + r[4] * ds ** 3


def _cut_width(poly, ref, s):
    """Length of the lane polygon cut along the reference line's normal at s."""
    x, y, h = ref(np.array([s]))
    n = np.array([-math.sin(h[0]), math.cos(h[0])])
    p = np.array([x[0], y[0]])
    cut = poly.intersection(shapely.LineString([p - 30 * n, p + 30 * n]))
    return cut.length


SYN_WIDTH = {  # (section, lane) -> width records relative to the section start
    (0, 1): [(0, 3.5, 0.02, -5e-4, 1e-6)], (0, 2): [(0, 2, 0, 0, 0)], (0, -1): [(0, 3.5, 0, 0, 0)],
    (0, -2): [(0, 0.5, -0.0125, 0, 0)], (0, -3): [(0, 2, 0, 0, 0)], (1, 1): [(0, 3.564, 0, 0, 0)],
    (1, 2): [(0, 2, 0, 0, 0)], (1, -1): [(0, 3.5, 0, 0, 0)], (1, -2): [(0, 0, 0.2, -0.01, 0), (25, 0, 0.1, 0, 0)],
    (1, -3): [(0, 2, 0, 0, 0)]}
SYN_SF = [(0, 0.02, 0, 0, 0), (50, 0.02, -0.001, 0, 0)]
SYN_ELEV = [(0, 1, 0.02, 0, 0), (40, 1.8, 0.02, 1e-4, 0)]


def _synth_t(k, lane, s):
    """Lateral offset of a lane's outer border (independent of the plugin)."""
    t = 0.2 + 0.01 * s
    sign = 1 if lane > 0 else -1
    for j in range(1, abs(lane) + 1):
        t += sign * max(_cubic(SYN_WIDTH[(k, sign * j)], s - 40 * k), 0.0)
    return t


def test_synthetic_map_every_segment_valid(synth):
    _, net = synth
    segs = net.layout.segments
    kinds = {s.kind for s in segs}
    assert kinds == {"driving", "sidewalk", "shoulder", "parking"}
    for seg in segs:
        seg.polygon()  # RoadSegment refuses degenerate or overlapping triangles
    # the parking lane is zero on s in [60, 65]: it splits into pieces with pointed tips
    parking = [s for s in segs if s.kind == "parking"]
    assert len(parking) == 2
    assert {s.attributes["laneSection"] for s in segs} == {0, 1}


def test_synthetic_widths_match_polynomials(synth):
    path, net = synth
    ref = ReferenceLine(read_xodr(path).roads[0].geometries)
    by_lane: dict[tuple[int, int], list] = {}
    for seg in net.layout.segments:
        by_lane.setdefault((seg.attributes["laneSection"], seg.attributes["lane"]), []).append(seg.polygon())
    worst = 0.0
    for (k, lane), polys in by_lane.items():
        area = shapely.union_all(polys)
        for s in np.arange(40 * k + 1.3, 40 * k + 39, 2.7):
            want = max(_cubic(SYN_WIDTH[(k, lane)], s - 40 * k), 0.0) * math.cos(_cubic(SYN_SF, s))
            got = _cut_width(area, ref, s)
            worst = max(worst, abs(got - want))
    # between samples the border is a chord: error <= max|w''| step^2 / 8 plus the curve's sagitta
    assert worst < 2e-3


def test_synthetic_lanes_share_borders_and_sections_share_cross_sections(synth):
    _, net = synth
    segs = net.layout.segments
    polys = [s.polygon() for s in segs]
    assert math.isclose(shapely.union_all(polys).area, sum(p.area for p in polys), rel_tol=1e-9)
    assert shapely.union_all(polys).geom_type == "Polygon"
    verts = {s.id: {tuple(v) for v in s.vertices[:, :2]} for s in segs}
    # lanes 1 and -1 (across the center lane) share every border vertex of each piece
    for seg in segs:
        if seg.attributes["lane"] == 1:
            twin = seg.id.replace("_lp1_", "_lm1_")
            assert len(verts[seg.id] & verts[twin]) == len(seg.centerline)
    # the last piece of section 0 and the first of section 1 share the s = 40 cross section
    assert len(verts["r7_ls0_lp1_1"] & verts["r7_ls1_lp1_0"]) == 2
    assert len(verts["r7_ls0_lm1_1"] & verts["r7_ls1_lm1_0"]) == 2


def test_synthetic_terrain_follows_elevation_and_superelevation(synth):
    path, net = synth
    ref = ReferenceLine(read_xodr(path).roads[0].geometries)
    terrain = net.layout.terrain
    from scipy.spatial import cKDTree

    tree = cKDTree(terrain[:, :2])
    checked = 0
    for s in np.arange(0.0, 39.0, 2.0):
        x, y, h = ref(np.array([s]))
        sf = _cubic(SYN_SF, s)
        for lane in (2, 1, -1, -2, -3):
            t = _synth_t(0, lane, s)
            xy = (x[0] - math.sin(h[0]) * t * math.cos(sf), y[0] + math.cos(h[0]) * t * math.cos(sf))
            d, i = tree.query(xy)
            assert d < 1e-6
            assert terrain[i, 2] == pytest.approx(_cubic(SYN_ELEV, s) + t * math.sin(sf), abs=1e-9)
            checked += 1
    assert checked == 100


def test_synthetic_centerlines_run_in_travel_direction(synth):
    path, net = synth
    ref = ReferenceLine(read_xodr(path).roads[0].geometries)
    for seg in net.layout.segments:
        c = seg.centerline
        d = c[-1] - c[0]
        x, y, h = ref(np.array([40.0 * seg.attributes["laneSection"] + 5]))
        along = d @ np.array([math.cos(h[0]), math.sin(h[0])])
        assert (along > 0) == (seg.attributes["lane"] < 0), seg.id


def test_metadata_and_rules(synth):
    path, net = synth
    meta = net.layout.metadata
    assert meta["geoReference"] == "+proj=tmerc +lat_0=1 +lon_0=2"
    assert meta["source"] == "synth.xodr" and "tests" in meta["attribution"]
    rules = net.layout.rules
    assert rules.kinds == ("driving", "junction") and rules.surface == "flat" and rules.merger == "cdt"


# ---- the small maps --------------------------------------------------------------------------

@pytest.mark.parametrize("path", [CURVED, CROSS])
def test_small_map_lane_widths(path):
    net = load_network(path)
    roads = {r.id: r for r in read_xodr(path).roads}
    tree = ET.parse(path).getroot()
    widths = {(r.get("id"), int(ln.get("id"))): float(ln.find("width").get("a"))
              for r in tree.iter("road") for ln in r.iter("lane") if ln.find("width") is not None}
    n = 0
    for seg in net.layout.segments:
        if seg.kind != "driving":
            continue
        road = seg.attributes["road"]
        ref = ReferenceLine(roads[road].geometries)
        poly = seg.polygon()
        ends = [shapely.Point(seg.centerline[0]), shapely.Point(seg.centerline[-1])]
        for s in np.linspace(0, roads[road].length, 97):
            x, y, _ = ref(np.array([s]))
            # cut only where the cross section is well inside this piece
            probe = shapely.Point(x[0], y[0])
            if min(probe.distance(e) for e in ends) < 4.0 or probe.distance(poly) > 1e-6:
                continue
            assert _cut_width(poly, ref, s) == pytest.approx(widths[(road, seg.attributes["lane"])], abs=2e-3)
            n += 1
    assert n > 20


@pytest.mark.parametrize("path", [CURVED, CROSS, TOWN01])
def test_no_gaps_no_overlaps(path, town01):
    net = town01 if path == TOWN01 else load_network(path)
    segs = net.layout.segments
    polys = [s.polygon() for s in segs]
    union = shapely.union_all(polys)
    total = sum(p.area for p in polys)
    assert total - union.area < 0.01  # m^2: only the junction snapping grid (0.1 mm) can overlap
    # neighbouring lanes of a piece share their border vertices exactly
    verts = {s.id: {tuple(v) for v in s.vertices[:, :2]} for s in segs}
    outer = [s for s in segs if s.attributes.get("lane") is not None and abs(s.attributes["lane"]) >= 2]
    for s in outer:
        lane = s.attributes["lane"]
        inner = s.id.replace(f"_l{'p' if lane > 0 else 'm'}{abs(lane)}_",
                             f"_l{'p' if lane > 0 else 'm'}{abs(lane) - 1}_")
        assert inner in verts, f"{s.id}: no inner neighbour {inner}"
        assert len(verts[s.id] & verts[inner]) >= len(s.centerline)
    # the file itself says whether there are pairs to check: lanes |id| >= 2 next to lanes |id| >= 1
    source_outer = [ln for ln in ET.parse(path).getroot().iter("lane") if abs(int(ln.get("id"))) >= 2]
    assert bool(outer) == bool(source_outer)


def test_curved_map_roads_are_exactly_one_meter_apart():
    net = load_network(CURVED)
    by_road = {}
    for s in net.layout.segments:
        by_road.setdefault(s.attributes["road"], []).append(s.polygon())
    a, b = (shapely.union_all(v) for v in by_road.values())
    assert a.geom_type == b.geom_type == "Polygon"
    assert a.distance(b) == pytest.approx(1.0, abs=1e-6)  # the map's GAP parameter


def test_intersection_junction_surface():
    net = load_network(CROSS)
    junctions = [s for s in net.layout.segments if s.kind == "junction"]
    assert [s.id for s in junctions] == ["junction_2"]  # the map's <junction id="2">
    j = junctions[0].polygon()
    assert j.geom_type == "Polygon" and junctions[0].centerline is None
    odr = read_xodr(CROSS)
    connecting = [r for r in odr.roads if r.junction != "-1"]
    assert len(connecting) == 6
    assert 300 < j.area < 23 * 23  # the rounded square inside the 23 m x 23 m box of the arms
    for seg in net.layout.segments:
        if seg.kind != "junction":
            assert seg.polygon().intersection(j).area < 1e-4
    # connecting lanes are kept as routes, not segments, in travel direction
    assert len(net.connecting_centerlines) == 12
    assert not any(s.attributes.get("road") in {r.id for r in connecting} for s in net.layout.segments)


# ---- Town01 ----------------------------------------------------------------------------------

def test_town01_counts(town01):
    assert town01.road_count == 122 and town01.junction_count == 12
    segs = town01.layout.segments
    assert len(segs) == 752  # 25 m pieces: 222 driving, 260 shoulder, 258 sidewalk, 12 junctions
    kinds = {k: sum(s.kind == k for s in segs) for k in ("driving", "junction", "shoulder", "sidewalk")}
    assert kinds == {"driving": 222, "junction": 12, "shoulder": 260, "sidewalk": 258}
    from pxr import Sdf

    assert all(Sdf.Path.IsValidIdentifier(s.id) for s in segs)
    assert len({s.id for s in segs}) == len(segs)
    assert town01.layout.rules.defect_count == 1000
    assert town01.layout.terrain.shape[1] == 3 and np.allclose(town01.layout.terrain[:, 2], 0.0)


def _town01_driving_area_reference() -> float:
    """Independent: sum over driving lanes outside junctions of the double integral of
    (1 - kappa(s) t) dt ds over the lane's lateral span (the exact area of an offset strip)."""
    root = ET.parse(TOWN01).getroot()
    total = 0.0

    def cubics(parent, tag, key="s"):
        return sorted((float(e.get(key)), *(float(e.get(c)) for c in "abcd")) for e in parent.iter(tag))

    for road in root.iter("road"):
        if road.get("junction") != "-1":
            continue
        length = float(road.get("length"))
        geoms = sorted((float(g.get("s")), float(g.find("arc").get("curvature")) if g.find("arc") is not None else 0.0)
                       for g in road.find("planView").iter("geometry"))
        offset = cubics(road.find("lanes"), "laneOffset")
        sections = road.find("lanes").findall("laneSection")
        for k, sec in enumerate(sections):
            s0 = float(sec.get("s"))
            s1 = float(sections[k + 1].get("s")) if k + 1 < len(sections) else length
            lanes = {int(ln.get("id")): (ln.get("type"), cubics(ln, "width", "sOffset")) for ln in sec.iter("lane")
                     if ln.get("id") != "0"}

            def border(lane, s):
                sign = 1 if lane > 0 else -1
                t = _cubic(offset, s) if offset else 0.0
                for j in range(1, abs(lane) + 1):
                    t += sign * _cubic(lanes[sign * j][1], s - s0)
                return t

            def kappa(s):
                return [kk for gs, kk in geoms if gs <= s + 1e-12][-1]

            breaks = sorted({g for g, _ in geoms if s0 < g < s1})
            for lane, (kind, _) in lanes.items():
                if kind != "driving":
                    continue
                inner = lane - 1 if lane > 0 else lane + 1

                def strip(s):
                    a, b = border(inner, s), border(lane, s)
                    return abs((b - a) - kappa(s) / 2 * (b * b - a * a))

                total += quad(strip, s0, s1, points=breaks or None, limit=200)[0]
    return total


def test_town01_driving_area_matches_independent_integral(town01):
    got = sum(s.polygon().area for s in town01.layout.segments if s.kind == "driving")
    want = _town01_driving_area_reference()
    # the polygons' borders are chords every <= 0.5 m: relative area deficit ~ (step kappa)^2 / 24 <= 1e-4
    assert got == pytest.approx(want, rel=1e-4)  # measured: 1.1e-5


def test_town01_junctions_do_not_overlap_roads(town01):
    segs = town01.layout.segments
    polys = [s.polygon() for s in segs]
    tree = shapely.STRtree(polys)
    worst = 0.0
    for i, s in enumerate(segs):
        if not s.id.startswith("junction_"):
            continue
        for j in tree.query(polys[i], predicate="intersects"):
            if j != i:
                worst = max(worst, polys[i].intersection(polys[j]).area)
    assert worst < 1e-3


def test_town01_connecting_lanes_are_routes(town01):
    c = town01.connecting_centerlines
    assert len(c) == 71  # driving lanes of the 96 connecting roads
    assert all(len(v) >= 2 and np.isfinite(v).all() for v in c.values())


def test_registered_and_params():
    imp = get_plugin_manager().get("layout_importers", "opendrive")
    assert isinstance(imp, OpenDriveImporter)
    layout = imp.load(CURVED, {"max_segment_length_m": 5.0})
    assert len(layout.segments) == 4 * math.ceil(44.347343 / 5.0)
    with pytest.raises(RoadtwinError, match="max_segment_length_m"):
        imp.load(CURVED, {"max_segment_length_m": float("nan")})
    with pytest.raises(RoadtwinError, match="unknown parameter"):
        imp.load(CURVED, {"bogus": 1})
    only = imp.load(TOWN01, OpenDriveParams(include_kinds=("driving",)))
    assert {s.kind for s in only.segments} == {"driving", "junction"}


# ---- errors ----------------------------------------------------------------------------------

def _road_xml(geometry="<line/>", lanes=None):
    lanes = lanes if lanes is not None else (
        '<lanes><laneSection s="0"><right><lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/>'
        "</lane></right></laneSection></lanes>")
    return ('<?xml version="1.0"?><OpenDRIVE><header/><road id="42" length="10" junction="-1"><planView>'
            f'<geometry s="0" x="0" y="0" hdg="0" length="10">{geometry}</geometry></planView>{lanes}</road>'
            "</OpenDRIVE>")


def _marked_lane(mark: str) -> str:
    return ('<lanes><laneSection s="0"><right><lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" '
            f'd="0"/>{mark}</lane></right></laneSection></lanes>')


BAD = {
    "unknown_geometry": (_road_xml("<clothoid2 k='1'/>"), "road 42: unknown geometry <clothoid2>"),
    "missing_lanes": (_road_xml(lanes=""), "road 42: has no <lanes>"),
    "no_lane_section": (_road_xml(lanes="<lanes/>"), "road 42: has no <laneSection>"),
    "only_center_lane": (_road_xml(lanes='<lanes><laneSection s="0"><center><lane id="0"/></center></laneSection>'
                                         "</lanes>"), "road 42: has no lanes"),
    "bad_number": (_road_xml('<arc curvature="0.1x"/>'), "road 42: <arc> attribute curvature='0.1x' is not a number"),
    "nan_number": (_road_xml('<arc curvature="nan"/>'), "road 42: <arc> attribute curvature='nan' is not finite"),
    "bad_xml": ('<?xml version="1.0"?><OpenDRIVE><road id="42"></OpenDRIVE>', "road 42: not well-formed XML"),
    "not_opendrive": ('<?xml version="1.0"?><svg/>', "not an OpenDRIVE file"),
    "roadmark_width": (_road_xml(lanes=_marked_lane('<roadMark sOffset="0" type="solid" width="0.1m"/>')),
                       "road 42: laneSection 0: lane -1: <roadMark> attribute width='0.1m' is not a number"),
    "roadmark_type": (_road_xml(lanes=_marked_lane('<roadMark sOffset="0" type="zigzag" width="0.1"/>')),
                      "road 42: laneSection 0: lane -1: <roadMark> type='zigzag' is not an OpenDRIVE road mark type"),
    "roadmark_line": (_road_xml(lanes=_marked_lane('<roadMark sOffset="0" type="broken"><type name="x" width="0.1">'
                                                   '<line length="3" space="-1" tOffset="0" sOffset="0"/></type>'
                                                   '</roadMark>')), "road 42: laneSection 0: lane -1: "),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_names_file_and_road(tmp_path, case):
    text, message = BAD[case]
    path = tmp_path / f"{case}.xodr"
    path.write_text(text)
    with pytest.raises(RoadtwinError) as exc:
        load_network(path)
    assert str(exc.value).startswith(f"{case}.xodr: ")
    assert message in str(exc.value)
    assert "\n" not in str(exc.value)


def test_cli_bad_input_exit_2_one_line(tmp_path):
    """bad XML, unknown geometry, missing lanes: exit 2, one line naming the file and road 42."""
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    procs = {}
    for case in ("bad_xml", "unknown_geometry", "missing_lanes"):  # concurrently: each pays the import of pxr
        path = tmp_path / f"{case}.xodr"
        path.write_text(BAD[case][0])
        procs[case] = subprocess.Popen([sys.executable, "-m", "roadtwin_core.cli", "import", "opendrive", str(path),
                                        "-o", str(tmp_path / f"{case}.usda")], cwd=REPO, env=env,
                                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for case, proc in procs.items():
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 2, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and BAD[case][1] in lines[0] and f"{case}.xodr" in lines[0], lines
        assert not (tmp_path / f"{case}.usda").exists()


def test_cli_import_and_compose_town01(tmp_path):
    layout = tmp_path / "town01.usda"
    r = cli("import", "opendrive", str(TOWN01.relative_to(REPO)), "-o", str(layout))
    assert r.returncode == 0, r.stderr
    assert "752 segments" in r.stdout
    out = tmp_path / "out"
    r = cli("compose", str(layout), "-o", str(out), "--defects", "50", "--surface", "flat", "--no-preview",
            timeout=300)
    assert r.returncode == 0, r.stderr
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert summary["validation"]["errors"] == 0
    assert summary["defects"] == 50 and summary["segments"] == 752


# ---- road marks --------------------------------------------------------------------------------

MARKED = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="6"/>
  <road id="5" length="60" junction="-1"><planView>
    <geometry s="0" x="10" y="20" hdg="0" length="60"><line/></geometry></planView>
    <lanes><laneOffset s="0" a="0.3" b="0" c="0" d="0"/>
      <laneSection s="0">
        <left><lane id="1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/>
          <roadMark sOffset="0" type="broken" color="white" width="0.15">
            <type name="custom" width="0.15"><line length="1" space="2" tOffset="0" sOffset="0.5"/></type>
          </roadMark></lane></left>
        <center><lane id="0" type="none">
          <roadMark sOffset="12" type="solid solid" color="yellow" width="0.1">
            <type name="double"><line length="0" space="0" tOffset="0.25" sOffset="0" width="0.1"/>
                                <line length="0" space="0" tOffset="0.05" sOffset="0" width="0.1"/></type>
          </roadMark>
          <roadMark sOffset="0" type="broken" color="standard"/>
          <roadMark sOffset="20" type="none"/>
          <roadMark sOffset="25" type="broken" color="yellow" width="0.12"/>
          <roadMark sOffset="28" type="broken" color="yellow" width="0.12"/>
        </lane></center>
        <right><lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/>
          <roadMark sOffset="0" type="custom" color="white" width="0.12">
            <type name="c"><line length="2" space="4" tOffset="-0.1" sOffset="1"/></type></roadMark>
          <roadMark sOffset="10" type="botts dots" color="white"/>
          <roadMark sOffset="30" type="curb" width="0.15"/>
          <roadMark sOffset="50" type="grass"/></lane></right>
      </laneSection>
      <laneSection s="40">
        <center><lane id="0" type="none"><roadMark sOffset="0" type="broken" color="yellow" width="0.12"/></lane></center>
        <right><lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/>
          <roadMark sOffset="0" type="solid broken" color="white" width="0.1"/></lane></right>
      </laneSection></lanes></road>
</OpenDRIVE>"""


@pytest.fixture(scope="module")
def marked(tmp_path_factory):
    path = tmp_path_factory.mktemp("odr") / "marked.xodr"
    path.write_text(MARKED)
    return {m.id: m for m in load_network(path).layout.markings}


def _span_of(m):
    """(x start, x end, y) of a marking on this straight road along +x from (10, 20)."""
    assert np.allclose(m.points[:, 1], m.points[0, 1])
    return m.points[0, 0] - 10, m.points[-1, 0] - 10, m.points[0, 1] - 20


def test_road_marks_spans_types_and_defaults(marked):
    """sOffsets listed out of order, 'none' and 'grass' skipped, a mark running to the section end,
    consecutive identical marks joined across a lane section, standard colour/width/dashes."""
    assert set(marked) == {"r5_ls0_c0_0", "r5_ls0_c0_1", "r5_ls0_c0_3", "r5_ls0_lp1_0", "r5_ls0_lm1_0",
                           "r5_ls0_lm1_1", "r5_ls0_lm1_2", "r5_ls1_lm1_0"}
    c0, c1, c3 = marked["r5_ls0_c0_0"], marked["r5_ls0_c0_1"], marked["r5_ls0_c0_3"]
    # centre lane: reference line + laneOffset 0.3, along +s
    assert _span_of(c0) == pytest.approx((0, 12, 0.3))
    assert (c0.marking_type, c0.color, c0.width_m, c0.dash_m, c0.gap_m) == ("broken", "white", 0.12, 3.0, 9.0)
    # solid solid: lines at t = 0.3 + 0.25 and 0.3 + 0.05 -> 0.2 apart around t = 0.45
    assert _span_of(c1) == pytest.approx((12, 20, 0.45))
    assert (c1.marking_type, c1.color, c1.width_m, c1.spacing_m) == ("solid_solid", "yellow", 0.1, pytest.approx(0.2))
    # s 25..28 and 28..40 and the next section's 0..20: one curve
    assert _span_of(c3) == pytest.approx((25, 60, 0.3))
    assert (c3.marking_type, c3.dash_m, c3.gap_m) == ("broken", 3.0, 9.0)
    bd, curb = marked["r5_ls0_lm1_1"], marked["r5_ls0_lm1_2"]
    assert _span_of(bd) == pytest.approx((10, 30, 0.3 - 3))
    assert (bd.marking_type, bd.width_m, bd.dash_m, bd.dash_m + bd.gap_m) == ("botts_dots", 0.1, 0.1, pytest.approx(1.2))
    assert _span_of(curb) == pytest.approx((30, 40, 0.3 - 3))  # grass at 50 paints nothing; section ends at 40
    assert (curb.marking_type, curb.color, curb.width_m) == ("curb", "white", 0.15)
    sb = marked["r5_ls1_lm1_0"]
    assert (sb.marking_type, sb.dash_m, sb.gap_m, sb.spacing_m) == ("solid_broken", 3.0, 9.0, pytest.approx(0.22))


def test_road_mark_line_definitions_and_travel_direction(marked):
    """<type><line>: dash/gap/phase from length/space/sOffset, tOffset moves the line; left lanes
    run against s, with the dash pattern mirrored."""
    custom = marked["r5_ls0_lm1_0"]
    assert _span_of(custom) == pytest.approx((0, 10, 0.3 - 3 - 0.1))
    assert (custom.marking_type, custom.dash_m, custom.gap_m, custom.phase_m) == ("broken", 2.0, 4.0, 1.0)
    left = marked["r5_ls0_lp1_0"]
    assert _span_of(left) == pytest.approx((40, 0, 3.3))  # lane 1 travels towards -s
    # dashes in s: [0.5 + 3k, 1.5 + 3k]; along the curve (u = 40 - s): [38.5 - 3k, 39.5 - 3k], which
    # start at u = 2.5 modulo the 3 m period
    assert (left.dash_m, left.gap_m, left.phase_m) == (1.0, 2.0, pytest.approx(2.5))
