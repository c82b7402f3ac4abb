"""OpenDRIVE ``<object>``s and ``<signal>``s: import to the world frame, compose into props.

Positions are checked against the closed form of a straight reference line (x0 + s cos h -
t sin h, y0 + s sin h + t cos h); Town01's against the same closed form evaluated straight from
the XML (xml.etree, none of the plugin's code) wherever its object lies on a ``<line>`` geometry.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdSemantics

from roadtwin_core import MapObject, RoadtwinError
from roadtwin_core.apps.compose import compose
from roadtwin_core.town.map_props import prototype_for, scale_for
from roadtwin_core.town.prop_shapes import make_prototype
from roadtwin_core.usd.layout_io import read_layout, write_layout
from roadtwin_opendrive import load_network

REPO = Path(__file__).resolve().parents[2]
TOWN01 = REPO / "tests" / "data" / "opendrive" / "Town01.xodr"
X0, Y0, H0 = 10.0, 20.0, 0.5          # the straight road's start and heading
ELEV = (2.0, 0.01)                     # elevation a + b s
HALF_WIDTH = 3.5                       # one 3.5 m driving lane each side of the reference line

ROAD = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="7" name="objects"/>
  <road id="1" length="100" junction="-1"><planView>
    <geometry s="0" x="{x0}" y="{y0}" hdg="{h0}" length="100"><line/></geometry></planView>
    <elevationProfile><elevation s="0" a="{e0}" b="{e1}" c="0" d="0"/></elevationProfile>
    <lanes><laneSection s="0">
      <left><lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
      <center><lane id="0" type="none"/></center>
      <right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
    </laneSection></lanes>
    <objects>
      <object id="tree1" type="tree" s="20" t="-8" zOffset="0.5" hdg="0" height="10"/>
      <object id="pole1" type="pole" s="40" t="6" hdg="0.3" height="9"/>
      <object id="car1" type="car" s="60" t="-1.75" hdg="0" length="4.4" width="1.8" height="1.5"/>
      <object id="walk1" type="crosswalk" s="80" t="0" length="4" width="7"/>
      <object id="wind1" type="wind" s="85" t="-9"/>
      <object id="lost1" type="pole" s="70" t="-1" height="6"/>
      <object id="rail1" type="barrier" s="10" t="-5" hdg="0"><repeat s="10" length="20" distance="0"/></object>
      <object id="bush1" type="vegetation" s="0" t="9" radius="1">
        <repeat s="0" length="30" distance="10" tStart="9" tEnd="12"/></object>
      {extra}
    </objects>
    <signals>
      <signal id="sig1" s="50" t="-4.5" zOffset="2" hOffset="0" orientation="+" dynamic="no" country="DE"
              type="274" subtype="53" height="0.6" width="0.6"/>
    </signals>
  </road>
</OpenDRIVE>
"""


def world(s, t):
    """Closed form of the straight reference line."""
    return (X0 + s * math.cos(H0) - t * math.sin(H0), Y0 + s * math.sin(H0) + t * math.cos(H0))


def road_st(xy):
    """(s, t) of world points on the straight road (the inverse of ``world``)."""
    d = np.asarray(xy, np.float64)[..., :2] - (X0, Y0)
    return d @ [math.cos(H0), math.sin(H0)], d @ [-math.sin(H0), math.cos(H0)]


def write_map(path: Path, extra: str = "") -> Path:
    path.write_text(ROAD.format(x0=X0, y0=Y0, h0=H0, e0=ELEV[0], e1=ELEV[1], extra=extra))
    return path


@pytest.fixture(scope="module")
def layout(tmp_path_factory):
    return load_network(write_map(tmp_path_factory.mktemp("odr") / "objects.xodr")).layout


def test_objects_land_where_the_reference_line_says(layout):
    by_id = {o.id: o for o in layout.objects}
    expect = {"tree1": (20, -8, 0.5, 0.0), "pole1": (40, 6, 0, 0.3), "car1": (60, -1.75, 0, 0.0)}
    for oid, (s, t, z_off, hdg) in expect.items():
        o = by_id[oid]
        assert np.allclose(o.position[:2], world(s, t), atol=1e-9), oid
        assert o.position[2] == pytest.approx(ELEV[0] + ELEV[1] * s + z_off)
        assert o.hpr[0] == pytest.approx(H0 + hdg)
    assert by_id["car1"].size == pytest.approx((4.4, 1.8, 1.5))
    assert by_id["tree1"].size == pytest.approx((0, 0, 10))
    sig = by_id["sig1"]     # orientation "+": for traffic along +s, so its face looks towards -s
    assert sig.kind == "signal" and sig.type == "274" and sig.subtype == "53"
    assert np.allclose(sig.position[:2], world(50, -4.5)) and sig.position[2] == pytest.approx(2 + 0.5 + 2)
    assert math.cos(sig.hpr[0] - (H0 + math.pi)) == pytest.approx(1.0)


def test_repeats_expand_along_s(layout):
    bushes = sorted((o for o in layout.objects if o.id.startswith("bush1_")), key=lambda o: o.id)
    assert [o.id for o in bushes] == [f"bush1_0_{j}" for j in range(4)]       # s = 0, 10, 20, 30
    for j, o in enumerate(bushes):
        assert np.allclose(o.position[:2], world(10 * j, 9 + j))   # t: 9 -> 12 over s 0 -> 30
        assert o.size == pytest.approx((2, 2, 0))                               # radius 1
    rails = sorted((o for o in layout.objects if o.id.startswith("rail1_")), key=lambda o: o.id)
    assert len(rails) == 5                                                      # 20 m continuous / 4 m pieces
    for j, o in enumerate(rails):
        assert np.allclose(o.position[:2], world(12 + 4 * j, -5))
        assert o.size[0] == pytest.approx(4.0) and o.hpr[0] == pytest.approx(H0)
    assert not any(o.id == "rail1" or o.id == "bush1" for o in layout.objects)  # replaced by their copies


def test_layout_round_trip(layout, tmp_path):
    read = read_layout(write_layout(layout, tmp_path / "objects.usda")).objects
    assert len(read) == len(layout.objects)
    for a, b in zip(layout.objects, read):
        assert (a.id, a.kind, a.type, a.subtype, a.name, a.road, a.dynamic) == \
               (b.id, b.kind, b.type, b.subtype, b.name, b.road, b.dynamic)
        assert np.allclose([a.position, a.hpr, a.size], [b.position, b.hpr, b.size])


@pytest.fixture(scope="module")
def town(layout, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("town")
    path = write_layout(layout, tmp / "objects.usda")
    result = compose(path, tmp / "out", defects=0, preview=False)
    return result.summary, Usd.Stage.Open(str(result.town))


def _instances(stage, group):
    inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(f"/objects/Props/{group}"))
    protos = inst.GetPrototypesRel().GetTargets()
    labels = [list(UsdSemantics.LabelsAPI(stage.GetPrimAtPath(p), "class").GetLabelsAttr().Get()) for p in protos]
    idx = np.asarray(inst.GetProtoIndicesAttr().Get())
    return np.asarray(inst.GetPositionsAttr().Get(), np.float64), [labels[i] for i in idx]


def test_composed_props_stand_at_the_map_objects(town):
    summary, stage = town
    assert summary["validation"]["errors"] == 0
    counts = summary["props"]["map_objects"]
    # 1 tree + 1 pole + 1 car + 4 bushes + 5 rail sections + 1 sign; the pole at t = -1 is on the lane
    assert counts == {"placed": 13, "skipped": {"crosswalk": 1, "wind": 1}, "on_driving_surface": {"pole": 1}}
    pos, labels = _instances(stage, "MapObjects")
    want = {("vegetation", "tree_round"): [world(20, -8)], ("pole", "utility_pole"): [world(40, 6)],
            ("sign", "sign_rect"): [world(50, -4.5)],
            ("vegetation", "shrub"): [world(10 * j, 9 + j) for j in range(4)],
            # 4 m sections run from x = 0: their origin is 2 m back from each piece's centre
            ("guardrail", "guardrail"): [world(10 + 4 * j, -5) for j in range(5)]}
    assert sorted(map(tuple, labels)) == sorted(k for k, v in want.items() for _ in v)
    for key, points in want.items():
        got = pos[[tuple(lab) == key for lab in labels], :2]
        assert np.allclose(sorted(map(tuple, got)), sorted(points), atol=1e-3), key
    cars, car_labels = _instances(stage, "MapVehicles")
    assert car_labels[0][0] == "vehicle" and np.allclose(cars[0, :2], world(60, -1.75), atol=1e-3)


def test_map_objects_never_stand_on_the_driving_surface(town):
    _, stage = town
    pos, labels = _instances(stage, "MapObjects")
    s, t = road_st(pos)
    assert (np.abs(t) > HALF_WIDTH).all(), t         # every non-vehicle is beside the two lanes
    assert len(_instances(stage, "MapVehicles")[0]) == 1


def cli(*args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    return subprocess.run([sys.executable, "-m", "roadtwin_core.cli", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("extra, message", [
    ('<object id="far1" type="tree" s="130" t="-8"/>', "object far1: s=130 lies outside the road (0..100 m)"),
    ('<object id="neg1" type="tree" s="10" t="-8" height="-2"/>', "object neg1: height=-2 is negative"),
    ('<object id="rep1" type="tree" s="10" t="-8"><repeat s="10" length="5" distance="-1"/></object>',
     "object rep1: repeat: length and distance must be >= 0"),
])
def test_bad_objects_are_one_line(tmp_path, extra, message):
    path = write_map(tmp_path / "bad.xodr", extra)
    with pytest.raises(RoadtwinError, match="bad.xodr: road 1: " + message.replace("(", r"\(").replace(")", r"\)")):
        load_network(path)
    if "far1" not in extra:      # the command line once: a subprocess costs seconds
        return
    r = cli("import", "opendrive", str(path), "-o", str(tmp_path / "bad.usda"))
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and message in lines[0], r.stderr
    assert not (tmp_path / "bad.usda").exists()


def _xml_line_pose(road: ET.Element, s: float, t: float):
    """World (x, y) of (s, t) on a road whose geometry at s is a <line>; None otherwise."""
    geoms = sorted(road.find("planView"), key=lambda g: float(g.get("s")))
    g = [g for g in geoms if float(g.get("s")) <= s + 1e-9][-1]
    if g.find("line") is None:
        return None
    h, ds = float(g.get("hdg")), s - float(g.get("s"))
    x, y = float(g.get("x")), float(g.get("y"))
    return x + ds * math.cos(h) - t * math.sin(h), y + ds * math.sin(h) + t * math.cos(h)


def test_town01_objects_and_signals_import_and_become_props():
    """Town01: 22 objects (speed-limit signs, type "-1", named Speed_30/60/90) and 36 signals
    (traffic lights, type 1000001, dynamic), no repeats."""
    root = ET.parse(TOWN01).getroot()
    expect = {}
    for road in root.iter("road"):
        for el in [*road.iter("object"), *road.iter("signal")]:
            expect[(el.tag, el.get("id"))] = _xml_line_pose(road, float(el.get("s")), float(el.get("t")))
    assert sum(k[0] == "object" for k in expect) == 22 and sum(k[0] == "signal" for k in expect) == 36
    objects = load_network(TOWN01).layout.objects
    assert len(objects) == 58
    on_lines = 0
    for o in objects:
        xy = expect[(o.kind, o.id)]
        if xy is not None:
            on_lines += 1
            assert np.allclose(o.position[:2], xy, atol=1e-6), o.id
    assert on_lines == 58          # all of them lie on <line> geometries
    assert sum(o.dynamic for o in objects) == 36
    protos = [prototype_for(o) for o in objects]
    assert protos.count("traffic_light") == 36 and protos.count("sign_rect") == 22


def _extent(name: str, scale) -> np.ndarray:
    """Size of a prototype's bounding box after scaling (x length, y width, z height)."""
    v = np.concatenate([part.vertices for part in make_prototype(name).parts]) * scale
    return v.max(axis=0) - v.min(axis=0)


@pytest.mark.parametrize("kind, subtype, size, proto, check", [
    ("tree", "", (0, 0, 12.0), "tree_round", {2: 12.0}),
    ("tree", "conifer", (0, 0, 7.0), "tree_conifer", {2: 7.0}),
    ("vegetation", "", (3.0, 3.0, 0), "shrub", {"plan": 3.0}),     # its larger plan extent
    ("vegetation", "grass", (0, 0, 0.5), "grass_tuft", {2: 0.5}),
    ("car", "", (5.0, 2.0, 1.6), None, {0: 5.0, 1: 2.0, 2: 1.6}),
    ("bus", "", (12.0, 2.55, 3.2), "bus", {0: 12.0, 1: 2.55, 2: 3.2}),
    ("pole", "", (0, 0, 6.0), "utility_pole", {2: 6.0}),
    ("pole", "delineator", (0, 0, 1.0), "km_post", {}),
    ("streetLamp", "", (0, 0, 10.0), "street_lamp", {2: 10.0}),
    ("barrier", "", (2.0, 0, 0), "guardrail", {}),
    ("barrier", "fence", (6.0, 0, 0), "fence", {}),
])
def test_map_objects_take_their_size(kind, subtype, size, proto, check):
    """The instance's scaled prototype has the map object's size along each axis the map gives."""
    obj = MapObject("o1", "object", kind, (0.0, 0.0, 0.0), size=size, subtype=subtype)
    name = prototype_for(obj)
    assert name == proto or (proto is None and name.startswith("car_"))
    ext = _extent(name, scale_for(obj, name))
    ext = {0: ext[0], 1: ext[1], 2: ext[2], "plan": max(ext[0], ext[1])}
    for axis, want in check.items():
        assert ext[axis] == pytest.approx(want, rel=1e-6), (name, axis)
    if kind == "barrier":      # sections: their ground length (post to section end) is the map's length
        fp = make_prototype(name).footprint
        assert (fp[2] - fp[0]) * scale_for(obj, name)[0] == pytest.approx(size[0])


def test_unknown_and_open_types():
    assert prototype_for(MapObject("a", "object", "crosswalk", (0, 0, 0))) is None
    assert prototype_for(MapObject("b", "object", "-1", (0, 0, 0), name="Speed_30")) == "sign_rect"
    assert prototype_for(MapObject("c", "object", "none", (0, 0, 0), name="thing")) is None
    assert prototype_for(MapObject("d", "signal", "1000001", (0, 0, 0), dynamic=True)) == "traffic_light"
    assert prototype_for(MapObject("e", "signal", "274", (0, 0, 0))) == "sign_rect"
