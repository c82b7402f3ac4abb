"""``roadtwin drive`` (issue 20) on the sample town: one clock, contacts, sensors, outputs, bad input.

One composed sample town and one drive, shared by every test here (module fixtures): the small
rig (``tests/data/small_rig.toml``: IMU 200 Hz, Mid-360-like LiDAR 10 Hz at 50,000 points/s,
RTK GNSS 10 Hz, a 96x64 stereo pair 10 Hz, a 96x72 camera looking at the front-right wheel
10 Hz) for 2.2 s at 30 km/h along lane ``avenue1_02_1`` of the sample town (seed 7), whose
pothole D00030 lies in the right wheel track 14 m in, on the warp backend (CPU): both right
wheels cross it. About 15 s on two cores, the composed town 8 s more. The same drive along
``--route auto`` (the stretch with the most defects in the wheel tracks) is ``bench/drive.py``.
Bad input goes through the command line, as a user types it (a subprocess each, ~3 s).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from roadtwin_core.plugins import PluginManager
from roadtwin_core.render import Camera, Intrinsics
from roadtwin_core.vehicle import DEFAULT_CAR

for _package in ("rosbags", "mcap", "open3d", "warp", "rerun"):
    pytest.importorskip(_package)

REPO = Path(__file__).resolve().parents[2]
RIG = REPO / "tests" / "data" / "small_rig.toml"
EPOCH_NS = 1_700_000_000 * 10**9        # the bag's stamps: the drive's clock + 1.7e9 s
LANE = "avenue1_02_1"                   # a pothole in its right wheel track, 14 m in
PARKED_LANE = "north_00_1"              # a car of the props layer stands in it, 15 m in


@pytest.fixture(scope="module")
def town(tmp_path_factory):
    from roadtwin_core.apps.compose.run import compose

    out = tmp_path_factory.mktemp("town") / "town"
    compose(REPO / "stages" / "town.usda", out, preview=False, executor="serial", pm=PluginManager())
    return out / "town.usda"


@pytest.fixture(scope="module")
def drive(town, tmp_path_factory):
    from roadtwin_core.apps.drive import DriveOptions, run_drive

    out = tmp_path_factory.mktemp("drive") / "drive"
    opt = DriveOptions(route=f"lane:{LANE}", length_m=None, duration_s=2.2, speed_kmh=30.0, rig=RIG)
    res = run_drive(town, out, opt, pm=PluginManager())
    return out, res


def _imu(out):
    a = np.loadtxt(out / "imu.csv", delimiter=",", skiprows=1)
    return a[:, 0], a[:, 3]


def _bag_messages(out, topic):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(out / "bag") as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [(t, ts.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages(connections=conns)]


# ------------------------------------------------------------------------------- synchronization
def test_contacts_are_found_and_written(drive):
    out, res = drive
    ev = json.loads((out / "contacts.json").read_text())
    assert ev == res["events"] and len(ev) >= 2
    assert res["route"] == f"lanes {LANE}" and res["defects_in_wheel_tracks"] == ["D00030"]
    potholes = [e for e in ev if e["defect_type"] == "pothole"]
    assert {e["wheel"] for e in potholes} >= {"FR", "RR"}          # the front wheel, then the rear one
    fr, rr = (next(e for e in potholes if e["wheel"] == w) for w in ("FR", "RR"))
    # the rear wheel meets the pothole one wheelbase later: 2.70 m at 30 km/h = 0.324 s
    assert abs((rr["t_entry_s"] - fr["t_entry_s"]) - DEFAULT_CAR.wheelbase_m / (30 / 3.6)) < 0.01
    assert (out / "contacts.csv").read_text().splitlines()[0].startswith("wheel,defect,")


def test_imu_peaks_fall_on_the_wheel_contacts(drive):
    """For each pothole crossed, the largest vertical-acceleration peak of the measured 200 Hz IMU
    (noise and bias included) over the crossing lies within one IMU sample of a wheel-contact
    event on that pothole. A sample stamped ``t`` is the mean over ``[t - dt, t)`` (a
    delta-velocity IMU), so "within one sample" is: that interval ends at most ``dt`` before the
    contact's entry and starts at most ``dt`` after its exit. On this pothole the largest peak is
    the front wheel climbing out of it, in the sample right after its contact patch leaves the
    footprint (the suspension passes the blow on in a few ms)."""
    out, res = drive
    t, az = _imu(out)
    dt = 1.0 / 200.0
    by_defect = {}
    for e in res["events"]:
        if e["defect_type"] == "pothole":
            by_defect.setdefault(e["defect"], []).append(e)
    assert by_defect
    for d, evs in by_defect.items():
        t0, t1 = min(e["t_entry_s"] for e in evs), max(e["t_exit_s"] for e in evs)
        w = (t >= t0 - 0.15) & (t <= t1 + 0.15)
        ref = np.median(az[(t > t0 - 1.0) & (t < t0 - 0.2)])
        k = np.argmax(np.abs(az[w] - ref))
        tp = t[w][k]
        assert any(e["t_entry_s"] - dt <= tp and tp - dt <= e["t_exit_s"] + dt for e in evs), (d, tp, evs)
        assert abs(az[w][k] - ref) > 0.5          # a real peak, not noise (BMI088: ~0.025 m/s^2 at 200 Hz)


def test_camera_frame_nearest_each_contact_shows_the_defect_under_the_wheel(drive):
    """The wheel camera's frame nearest each front-right contact shows that defect (its instance
    id in the frame's ground truth) where the tire meets the road, projected through the rig."""
    out, res = drive
    traj = res["trajectory"]
    inst_of = {v: int(k) for k, v in res["instances"].items()}
    frames = [f for f in json.loads((out / "frames.json").read_text()) if f["sensor"] == "wheelcam"]
    ft = np.array([f["t"] for f in frames])
    inst_msgs = _bag_messages(out, "/wheelcam/instance")
    info = _bag_messages(out, "/wheelcam/camera_info")[0][1]
    K = info.k.reshape(3, 3)
    intr = Intrinsics(int(info.width), int(info.height), K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    c = DEFAULT_CAR.corner(1)                                   # FR
    checked = 0
    for e in res["events"]:
        if e["wheel"] != "FR":
            continue
        tm = 0.5 * (e["t_entry_s"] + e["t_exit_s"])            # the wheel is on the defect
        k = int(np.argmin(np.abs(ft - tm)))
        assert abs(ft[k] - tm) <= 0.5 / res["sensors"]["wheelcam"]["rate_hz"] + 1e-9
        pose = traj.pose_at(tm)
        p = pose[:3, :3] @ np.array([c["x"], c["y"], 0.0]) + pose[:3, 3]
        p[2] = np.interp(tm, traj.t, traj.wheel_z[:, 1]) - DEFAULT_CAR.tire_radius_m   # where the tire meets the road
        uv, z = Camera(intr, np.array(frames[k]["cam_to_world"])).project(p[None])
        u, v = np.round(uv[0]).astype(int)
        assert z[0] > 0 and 0 <= u < intr.width and 0 <= v < intr.height, (u, v)
        img = inst_msgs[k][1]
        inst = np.frombuffer(img.data.tobytes(), np.uint16).reshape(img.height, img.width)
        patch = inst[max(v - 2, 0):v + 3, max(u - 2, 0):u + 3]
        assert inst_of[e["defect"]] in patch, (e, patch)
        assert inst_msgs[k][0] == EPOCH_NS + round(ft[k] * 1e9)     # stamped at the sample's time on the one clock
        checked += 1
    assert checked >= 1


# ------------------------------------------------------------------------------- outputs read back
def test_bag_reads_back_with_rosbags(drive):
    from rosbags.rosbag2 import Reader

    out, res = drive
    n = {s: v["samples"] for s, v in res["sensors"].items()}
    want = {"/imu/imu": ("sensor_msgs/msg/Imu", n["imu"]), "/gnss/fix": ("sensor_msgs/msg/NavSatFix", n["gnss"]),
            "/lidar/points": ("sensor_msgs/msg/PointCloud2", n["lidar"]),
            "/stereo/left/image_raw": ("sensor_msgs/msg/Image", n["stereo"]),
            "/stereo/right/camera_info": ("sensor_msgs/msg/CameraInfo", n["stereo"]),
            "/wheelcam/image_raw": ("sensor_msgs/msg/Image", n["wheelcam"]),
            "/wheelcam/instance": ("sensor_msgs/msg/Image", n["wheelcam"]),
            "/ground_truth/odom": ("nav_msgs/msg/Odometry", None),
            "/tf_static": ("tf2_msgs/msg/TFMessage", 1), "/tf": ("tf2_msgs/msg/TFMessage", None)}
    dur = res["duration_s"]
    assert n["imu"] == int(dur * 200) and n["lidar"] == int(dur * 10) and n["wheelcam"] == int(dur * 10)
    assert "storage_identifier: mcap" in (out / "bag" / "metadata.yaml").read_text()
    with Reader(out / "bag") as reader:
        got = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    for topic, (mtype, count) in want.items():
        assert got[topic][0] == mtype, topic
        if count is not None:
            assert got[topic][1] == count, topic
    assert dict(sorted((t, c) for t, (_, c) in got.items())) == res["bag_topics"]
    # a PointCloud2 decodes: points in range, labels of the town's classes
    _, pc = _bag_messages(out, "/lidar/points")[5]
    assert pc.width > 1000 and pc.point_step * pc.width == len(pc.data)
    # GNSS RTK fix near the town's origin on the globe
    fix = _bag_messages(out, "/gnss/fix")[0][1]
    assert fix.status.status == 2 and abs(fix.latitude - 31.2304) < 0.01


def test_mcap_reads_with_mcaps_reader(drive):
    from mcap.reader import make_reader

    out, res = drive
    (path,) = (out / "bag").glob("*.mcap")
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    topics = {ch.topic: ch.message_encoding for ch in summary.channels.values()}
    assert topics["/imu/imu"] == "cdr"
    schemas = {s.name for s in summary.schemas.values()}
    assert {"sensor_msgs/msg/Imu", "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/NavSatFix",
            "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"} <= schemas
    assert summary.statistics.message_count == sum(res["bag_topics"].values())


def test_rrd_loads_in_rerun(drive):
    out, _ = drive
    exe = Path(sys.executable).with_name("rerun")
    if not exe.exists():
        pytest.skip("rerun CLI not installed")
    r = subprocess.run([str(exe), "rrd", "print", str(out / "drive.rrd")], capture_output=True, text=True,
                       timeout=60, env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert r.returncode == 0, r.stderr
    for entity in ("world/route", "world/defects", "world/lidar", "world/wheelcam", "imu/imu/acc_z", "events"):
        assert entity in r.stdout


# ------------------------------------------------------------------------------------ bad input
def _cli(*args):
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    return subprocess.run([sys.executable, "-m", "roadtwin_core.cli", "drive", *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=120, cwd=REPO)


@pytest.mark.parametrize("case", ["off_road", "no_sensor", "other_vehicle", "parked_car", "param_no_sensor",
                                  "param_unknown_key", "param_malformed"])
def test_bad_input_is_one_line_and_nothing_written(town, tmp_path, case):
    """A route that leaves the road, a rig without the sensor named, a sweep's speed profile for
    another vehicle, a lane with a car standing in it: one line on stderr, exit 2, and an earlier
    output stays as it was (no temporary folder beside it)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "earlier.txt").write_text("an earlier drive")
    args = [town, "-o", out, "--rig", RIG, "--sensors", "imu"]
    if case == "off_road":
        route = tmp_path / "route.txt"
        route.write_text("-120 0\n-60 0\n-60 300\n")           # turns off the street into the blocks
        args += ["--route", route]
        expect = "leaves the road"
    elif case == "no_sensor":
        args[-1] = "imu,thermal"
        expect = "has no sensor 'thermal'"
    elif case == "other_vehicle":
        prof = tmp_path / "recommendations.json"
        prof.write_text(json.dumps([{"defect": "D00021", "vehicle": "truck", "recommended_speed_kmh": 10}]))
        args += ["--speed-profile", prof]
        expect = "is for vehicle truck"
    elif case == "param_no_sensor":                            # a sensor the selection does not record
        args += ["--sensor-param", "lidar.points_per_s=1000"]
        expect = "records no sensor 'lidar'"
    elif case == "param_unknown_key":
        args += ["--sensor-param", "imu.colour=3"]
        expect = "unknown parameter(s) colour"
    elif case == "param_malformed":
        args += ["--sensor-param", "width=1280"]
        expect = "expected SENSOR.KEY=VALUE"
    elif case == "parked_car":
        args += ["--route", f"lane:{PARKED_LANE}"]
        expect = "runs into /Town/Props/LaneVehicles instance"
    else:
        raise AssertionError(case)
    r = _cli(*args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and expect in lines[0], r.stderr
    assert [p.name for p in out.iterdir()] == ["earlier.txt"] and (out / "earlier.txt").read_text() == "an earlier drive"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out", *(["route.txt"] if case == "off_road" else []),
                                                                 *(["recommendations.json"] if case == "other_vehicle"
                                                                   else [])])


# ------------------------------------------------------------------------------------ route and speed
def test_auto_route_and_a_sweeps_speed_profile(town, tmp_path):
    """``--route auto`` takes the stretch whose wheel tracks meet the most defects; a sweep's
    recommendations for the driven vehicle slow it over those defects (10 m before to 3 m after)
    and leave the cruise speed elsewhere. Nothing is driven (``prepare_drive`` only)."""
    from roadtwin_core.apps.drive import DriveOptions, prepare_drive

    recs = [{"defect": "D00021", "vehicle": DEFAULT_CAR.name, "recommended_speed_kmh": 12.0},
            {"defect": "D00029", "vehicle": DEFAULT_CAR.name, "recommended_speed_kmh": 18.0},
            {"defect": "D00029", "vehicle": "truck", "recommended_speed_kmh": 5.0}]
    (tmp_path / "recommendations.json").write_text(json.dumps(recs))
    opt = DriveOptions(route="auto", length_m=60.0, speed_kmh=30.0, rig=RIG, sensors="imu",
                       speed_profile=tmp_path / "recommendations.json")
    ctx = prepare_drive(town, opt, pm=PluginManager())
    route, hits = ctx["route"], {h["id"]: h for h in ctx["hits"]}
    assert route.source.startswith("auto: lanes ") and abs(route.length - 60.0) < 1e-6
    assert {"D00021", "D00029"} <= set(hits)
    pieces = ctx["profile"].pieces(route.length)
    speed_at = {d: next(v for a, b, v in pieces if a <= hits[d]["s"] < b) * 3.6 for d in ("D00021", "D00029")}
    assert speed_at == pytest.approx({"D00021": 12.0, "D00029": 18.0})
    assert pieces[0][2] * 3.6 == pytest.approx(30.0) and pieces[-1][2] * 3.6 == pytest.approx(30.0)
    assert {"D00021", "D00029"} <= set(ctx["footprints"]) < {d.id for d in ctx["town"].defects}   # the reachable ones


def _standing_cars(stage: Path):
    """The plan outline (shapely) of every instance of the props' lane vehicles, read with pxr:
    each prototype's bounding box, placed by its instance's transform."""
    from pxr import Gf, Usd, UsdGeom
    from shapely.geometry import Polygon

    st = Usd.Stage.Open(str(stage))
    pi = UsdGeom.PointInstancer(st.GetPrimAtPath("/Town/Props/LaneVehicles"))
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default", "render"])
    boxes = [cache.ComputeUntransformedBound(st.GetPrimAtPath(p)).ComputeAlignedRange()
             for p in pi.GetPrototypesRel().GetTargets()]
    out = []
    for xf, k in zip(pi.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default()),
                     pi.GetProtoIndicesAttr().Get()):
        lo, hi = boxes[k].GetMin(), boxes[k].GetMax()
        corners = [Gf.Matrix4d(xf).Transform(Gf.Vec3d(x, y, 0.0)) for x, y in
                   ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1]))]
        out.append(Polygon([(c[0], c[1]) for c in corners]))
    return out


def test_auto_route_keeps_clear_of_the_cars_standing_in_lanes(town):
    """The sample town's longest chain of lanes (320 m) has two cars of the props layer standing
    in it; a 300 m ``--route auto`` drive keeps the body (``body_width_m`` x ``body_length_m``
    about each route point, along it) clear of every such car."""
    from shapely.geometry import Polygon

    from roadtwin_core.apps.drive import DriveOptions, prepare_drive

    cars = _standing_cars(town)
    assert len(cars) >= 3
    ctx = prepare_drive(town, DriveOptions(route="auto", length_m=300.0, rig=RIG, sensors="imu"), pm=PluginManager())
    route, w, length = ctx["route"], ctx["vehicle"].body_width_m, ctx["vehicle"].body_length_m
    p, t = route.at(np.arange(0.0, route.length, 0.25))
    n = np.column_stack([-t[:, 1], t[:, 0]])
    bodies = [Polygon([c + a * length / 2 * ti + b * w / 2 * ni for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
              for c, ti, ni in zip(p, t, n)]
    for car in cars:
        assert min(b.distance(car) for b in bodies) > 0.0, (car.centroid, route.source)
    # the reader's outlines (TownInstances.corners) are pxr's
    from roadtwin_core.apps.drive.obstacles import lane_obstacles

    mine = [Polygon(o.corners) for o in lane_obstacles(ctx["town"]) if o.where.startswith("/Town/Props/LaneVehicles ")]
    assert len(mine) == len(cars)
    assert all(a.symmetric_difference(b).area < 1e-6 * a.area for a, b in zip(mine, cars))


# ------------------------------------------------------------------------------------ many drives
TINY_RIG = """name = "tiny"
[[sensor]]
name = "imu"
type = "imu"
rate_hz = 200
xyz = [0.3, 0.0, 1.05]
[[sensor]]
name = "lidar"
type = "lidar"
rate_hz = 10
xyz = [0.3, 0.0, 1.0]
ypr_deg = [0.0, -45.0, 0.0]
[sensor.params]
points_per_s = 5000
[[sensor]]
name = "cam"
type = "camera"
rate_hz = 10
xyz = [0.6, 0.06, 0.95]
ypr_deg = [0.0, -12.0, 0.0]
[sensor.params]
width = 32
height = 24
max_subframes = 1
"""
ROUTES = [f"lane:{LANE}", "lane:street0_0_00_1"]


def _files(folder: Path) -> dict[str, bytes]:
    """Every file's bytes but the wall times (``timings.json``); rerun stamps each row of a
    ``.rrd`` with a time-based id, so these drives write none."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "timings.json"}


def _many(town, out, executor, rig, **kw):
    from roadtwin_core.apps.drive import DriveOptions, run_drives

    opt = DriveOptions(length_m=None, duration_s=0.3, speed_kmh=30.0, rig=rig, rrd=False)
    return run_drives(town, out, opt, ROUTES, executor=executor, **kw)


@pytest.fixture(scope="module")
def tiny_rig(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig") / "tiny.toml"
    path.write_text(TINY_RIG)
    return path


@pytest.fixture(scope="module")
def serial_drives(town, tiny_rig, tmp_path_factory):
    out = tmp_path_factory.mktemp("many") / "serial"
    return out, _many(town, out, "serial", tiny_rig)


def test_many_routes_one_folder_each_same_bytes_on_a_process_pool(town, tiny_rig, serial_drives, tmp_path):
    """Two routes, one drive each in ``route_000``/``route_001``: each drives its own lane (the
    body starts on that lane's centreline) and writes what one ``run_drive`` of that route writes;
    a pool of two forked workers writes the same bytes as the serial executor."""
    from roadtwin_core.apps.drive import DriveOptions, run_drive
    from roadtwin_core.render import stage_lanes

    out, res = serial_drives
    listing = json.loads((out / "drives.json").read_text())["drives"]
    assert [d["folder"] for d in listing] == ["route_000", "route_001"] and res["executor"] == "serial"
    lanes = {ln.id: ln for ln in stage_lanes(town)}
    for d, spec in zip(listing, ROUTES):
        lane = lanes[spec.split(":")[1]]
        start = np.loadtxt(out / d["folder"] / "trajectory.csv", delimiter=",", skiprows=1)[0, 1:3]
        assert np.linalg.norm(start - lane.points[0]) < 0.5, (spec, start, lane.points[0])
        assert d["samples"] == {"imu": 60, "lidar": 3, "cam": 3}
    single = tmp_path / "single"
    run_drive(town, single, DriveOptions(route=ROUTES[1], length_m=None, duration_s=0.3, speed_kmh=30.0,
                                         rig=tiny_rig, rrd=False), pm=PluginManager())
    assert _files(single) == _files(out / "route_001")
    pooled = tmp_path / "local"
    assert _many(town, pooled, "local", tiny_rig, workers=2)["executor"] == "local"
    assert _files(pooled) == _files(out)


def test_many_routes_a_bad_route_is_one_line_naming_it(town, tiny_rig, tmp_path):
    from roadtwin_core import RoadtwinError
    from roadtwin_core.apps.drive import DriveOptions, run_drives

    off_road = tmp_path / "route.txt"
    off_road.write_text("-120 0\n-60 0\n-60 300\n")
    opt = DriveOptions(length_m=None, duration_s=0.3, rig=tiny_rig, rrd=False)
    with pytest.raises(RoadtwinError, match=r"^route 1 \(.*route\.txt\): .*leaves the road"):
        run_drives(town, tmp_path / "out", opt, [ROUTES[0], str(off_road)], executor="serial")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["route.txt"]


@pytest.mark.slow
def test_many_routes_on_a_local_ray_cluster_same_bytes_as_serial(town, tiny_rig, serial_drives, tmp_path):
    """The same two drives as Ray tasks on a local two-CPU cluster: the same bytes (~40 s)."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        res = _many(town, tmp_path / "ray", "ray", tiny_rig)
    finally:
        ray.shutdown()
    assert res["executor"] == "ray"
    assert _files(tmp_path / "ray") == _files(serial_drives[0])


def test_cameras_developed_on_the_renderers_device_are_the_host_cameras(town, tmp_path, monkeypatch):
    """A drive's stereo pair developed by the renderer where it renders (on CUDA; forced here on
    the CPU device) shows what the host's camera model shows: the same labels, each eye's image
    within rounding of the host's (read noise off: the two paths draw other numbers)."""
    from roadtwin_core.apps.drive import DriveOptions, run_drive
    from roadtwin_core.apps.drive.world import World

    rig = tmp_path / "stereo.toml"
    rig.write_text('name = "pair"\n[[sensor]]\nname = "stereo"\ntype = "stereo"\nrate_hz = 10\nxyz = [0.6, 0.06, 0.95]\n'
                   'ypr_deg = [0.0, -12.0, 0.0]\n[sensor.params]\nwidth = 96\nheight = 64\nhfov_deg = 80.0\n'
                   'read_noise = 0.0\nexposure_s = 0.02\n')
    opt = DriveOptions(route=f"lane:{LANE}", length_m=None, duration_s=0.45, speed_kmh=30.0, rig=rig)
    from roadtwin_warp_render.renderer import WarpRenderer

    developed = []
    render_exposed = WarpRenderer.render_exposed
    monkeypatch.setattr(WarpRenderer, "render_exposed", lambda self, *a, **k: developed.append(1) or
                        render_exposed(self, *a, **k))
    outs = {}
    for device in (False, True):
        monkeypatch.setattr(World, "expose_on_any_device", device)
        outs[device] = tmp_path / f"device_{device}"
        run_drive(town, outs[device], opt, pm=PluginManager())

    def images(out, topic):
        msgs = _bag_messages(out, topic)
        return [np.frombuffer(m.data.tobytes(), np.uint8).reshape(m.height, m.width, -1).astype(int) for _, m in msgs]

    for topic in ("/stereo/left/image_raw", "/stereo/right/image_raw", "/stereo/semantic", "/stereo/instance", "/stereo/depth"):
        host, dev = images(outs[False], topic), images(outs[True], topic)
        assert len(host) == len(dev) >= 4, topic
        for a, b in zip(host, dev):
            if topic.endswith("image_raw"):
                assert np.abs(a - b).max() <= 2 and np.abs(a - b).mean() < 0.1, topic
            else:
                np.testing.assert_array_equal(a, b)
    left, right = images(outs[True], "/stereo/left/image_raw"), images(outs[True], "/stereo/right/image_raw")
    assert np.abs(left[0] - right[0]).mean() > 1.0           # the right eye is its own view
    assert len(developed) == len(left)                        # one call a pair, on the forced drive only


def test_sensor_params_over_the_rig_files(town, tiny_rig, tmp_path):
    """``--sensor-param cam.width=40`` (``DriveOptions.sensor_params``): the camera records at the
    size given, not the rig file's 32 x 24, and its CameraInfo says so; the rig file is untouched."""
    from roadtwin_core.apps.drive import DriveOptions, run_drive

    before = tiny_rig.read_bytes()
    opt = DriveOptions(route=ROUTES[0], length_m=None, duration_s=0.2, speed_kmh=30.0, rig=tiny_rig, sensors="cam",
                       sensor_params={"cam": {"width": 40, "height": 30}}, rrd=False)
    run_drive(town, tmp_path / "out", opt, pm=PluginManager())
    infos = [m for _, m in _bag_messages(tmp_path / "out", "/cam/camera_info")]
    images = [m for _, m in _bag_messages(tmp_path / "out", "/cam/image_raw")]
    assert infos and all((i.width, i.height) == (40, 30) for i in infos)
    assert images and all((m.width, m.height, len(m.data)) == (40, 30, 40 * 30 * 3) for m in images)
    assert tiny_rig.read_bytes() == before
