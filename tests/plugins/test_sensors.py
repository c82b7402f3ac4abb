"""The built-in sensor models (``roadtwin_sensors``) on a vehicle whose motion is known in closed
form, seeing the plane z = 0: noise levels against their data-sheet figures, the LiDAR's
per-point timing, the cameras' motion blur. No town, no physics (a fraction of a second); the
sensors on a real drive are tests/apps/test_drive.py."""
from __future__ import annotations

import importlib
import math
from types import SimpleNamespace

import numpy as np
import pytest

from roadtwin_core import RoadtwinError, contracts
from roadtwin_core.plugins import PluginManager
from roadtwin_core.render import Camera, StereoCamera

from fakes import FakeRenderer, plane_view

rs = importlib.import_module("roadtwin_sensors")
G = 9.80665


class Cruise:
    """The body at ``height`` m above z = 0, driving along +x at ``speed`` m/s, yawed by nothing:
    the :class:`roadtwin_core.apps.drive.SensorState` interface, in closed form."""

    def __init__(self, t: float, speed: float = 0.0, height: float = 0.5) -> None:
        self.t, self.speed, self.height = t, speed, height

    def pose_at(self, t):
        t = np.asarray(t, np.float64)
        m = np.zeros(t.shape + (4, 4))
        m[..., :3, :3] = np.eye(3)
        m[..., 0, 3] = self.speed * t
        m[..., 2, 3] = self.height
        m[..., 3, 3] = 1.0
        return m

    def velocity_at(self, t):
        return np.array([self.speed, 0.0, 0.0])

    def imu_truth(self, offset, t0, t1):
        return np.array([0.0, 0.0, G]), np.zeros(3)


def plane_world():
    """``world`` services of a scene that is the plane z = 0 (class 1 ``driving``)."""
    scene = SimpleNamespace(classes=["background", "driving"])
    renderer = FakeRenderer()

    def cast(origins, dirs):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -origins[:, 2] / dirs[:, 2]
        t = np.where(np.isfinite(t) & (t > 0), t, np.inf)
        hit = np.isfinite(t)
        return {"t": t, "class_id": hit.astype(np.int32), "instance": np.zeros(len(t), np.int32)}

    return SimpleNamespace(render=lambda cameras: list(renderer.render(scene, cameras)), cast=cast,
                           class_names=scene.classes, renderer=renderer)


def mount(kind: str, rate_hz: float, extrinsic=None, sensor_id: str = "s", **params):
    pm = PluginManager(load_entry_points=False)
    pm.register(rs, name="sensors")
    sensor_type = pm.get("sensors", kind)
    return sensor_type.create(sensor_id, rate_hz, np.eye(4) if extrinsic is None else extrinsic,
                              sensor_type.Params(**params))


def test_builtins_register_and_meet_the_contract():
    pm = PluginManager(load_entry_points=False)
    pm.register(rs, name="sensors")
    info = pm.load_all()
    assert info["sensors"].error == ""
    registry = pm.registry("sensors")
    assert sorted(registry) == ["camera", "gnss", "imu", "lidar", "stereo"]
    for thing in registry.values():
        assert contracts.check("sensors", thing) == [] and thing.description
    bad = SimpleNamespace(name="x", description="", Params=rs.ImuParams, message="sonar", create=lambda a, b, c, d: 0)
    assert contracts.check("sensors", bad) == ["message must be one of imu, gnss, image, stereo, points, got 'sonar'"]


def test_imu_at_rest_reads_gravity_with_the_datasheet_noise():
    """White noise per sample = density x sqrt(rate): BMI088 typical 175 ug/sqrt(Hz) and
    0.014 deg/s/sqrt(Hz) at 200 Hz are 0.0243 m/s^2 and 0.00346 rad/s; the turn-on bias is
    within a few sigma of the zero-g / zero-rate offsets (20 mg, 1 deg/s)."""
    imu = mount("imu", 200.0, seed=3)
    samples = [imu.sample(Cruise(k / 200.0), None) for k in range(1, 4001)]
    acc = np.array([s["linear_acceleration"] for s in samples])
    gyro = np.array([s["angular_velocity"] for s in samples])
    assert acc.std(0) == pytest.approx(np.full(3, 175e-6 * G * math.sqrt(200)), rel=0.1)
    assert gyro.std(0) == pytest.approx(np.full(3, math.radians(0.014) * math.sqrt(200)), rel=0.1)
    assert np.all(np.abs(acc.mean(0) - [0.0, 0.0, G]) < 4 * 20e-3 * G)
    assert np.all(np.abs(gyro.mean(0)) < 4 * math.radians(1.0))
    assert samples[0]["accel_var"] == pytest.approx((175e-6 * G) ** 2 * 200)
    np.testing.assert_allclose(samples[0]["orientation"], [0.0, 0.0, 0.0, 1.0])


def test_gnss_rtk_is_centimetres_and_standalone_metres():
    def horizontal_errors(mode):
        gnss = mount("gnss", 10.0, mode=mode, seed=1)
        errors = []
        for k in range(1, 601):
            s = gnss.sample(Cruise(k / 10.0, speed=10.0), None)
            lat, lon, _ = rs.enu_to_geodetic(s["truth"]["enu"], 31.2304, 121.4737, 10.0)
            errors.append([(s["longitude"] - lon) * 111320 * math.cos(math.radians(lat)), (s["latitude"] - lat) * 110574])
        return np.linalg.norm(np.array(errors), axis=1)

    rtk, sps = horizontal_errors("rtk"), horizontal_errors("sps")
    assert np.median(rtk) < 0.03 and 0.3 < np.median(sps) < 5.0
    with pytest.raises(RoadtwinError, match="gnss mode must be rtk or sps"):
        mount("gnss", 10.0, mode="ppp")


def test_lidar_points_land_on_the_plane_from_a_moving_body():
    """Mid-360 coverage (360 degrees, -7 to 52 degrees elevation); each point is cast from the
    sensor's pose at its own time and returned in the sensor frame at that time, so mapping it
    back with that pose puts it on the plane (within the 2 cm range noise) although the body
    moves 1.5 m during the frame."""
    d = rs.mid360_directions(20000, 0.0, 0.1)
    el = np.degrees(np.arcsin(d[:, 2]))
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    assert el.min() >= -7.0 - 1e-9 and el.max() <= 52.0 + 1e-9 and el.max() - el.min() > 50
    assert np.histogram(az, bins=8, range=(-180, 180))[0].min() > 1000
    tilt = np.eye(4)
    tilt[:3, :3] = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]   # pitched 90 deg: looking down
    tilt[:3, 3] = [0.3, 0.0, 1.0]
    lidar = mount("lidar", 10.0, tilt, points_per_s=50000.0)
    state = Cruise(0.5, speed=15.0, height=0.5)
    s = lidar.sample(state, plane_world())
    assert s["t"] == pytest.approx(0.4) and len(s["xyz"]) > 1000
    T = state.pose_at(s["t"] + s["time_offset_s"].astype(np.float64)) @ lidar.extrinsic
    world = np.einsum("nij,nj->ni", T[:, :3, :3], s["xyz"].astype(np.float64)) + T[:, :3, 3]
    assert np.abs(world[:, 2]).max() < 0.1 and np.abs(world[:, 2]).std() < 0.03
    assert set(np.unique(s["label"])) == {1}


def test_camera_blurs_only_when_the_image_moves():
    """Sub-frames across the 8 ms exposure as the image moves pixels: one when the body stands
    still, several (odd, the middle one gives the labels) when a sideways camera passes the
    road at 30 m/s; the stereo pair renders both eyes of each."""
    sideways = np.eye(4)
    sideways[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]      # yaw 90 deg: looking left
    down = np.eye(4)
    down[:3, :3] = [[math.cos(1.0), 0.0, math.sin(1.0)], [0.0, 1.0, 0.0], [-math.sin(1.0), 0.0, math.cos(1.0)]]
    ext = sideways @ down
    ext[:3, 3] = [0.0, 1.0, 1.0]
    cam = mount("camera", 20.0, ext, width=48, height=32, max_subframes=5, read_noise=0.0)
    world = plane_world()
    still = cam.sample(Cruise(0.5, speed=0.0), world)
    moving = cam.sample(Cruise(0.5, speed=30.0), world)
    assert still["subframes"] == 1 and moving["subframes"] in (3, 5)
    assert moving["rgb"].shape == (32, 48, 3) and moving["rgb"].dtype == np.uint8
    _, hit = plane_view(Camera(moving["intrinsics"], np.asarray(moving["cam_to_world"])))
    assert hit.any() and np.array_equal(moving["semantic"] > 0, hit)
    pair = mount("stereo", 10.0, ext, width=48, height=32, max_subframes=3)
    s = pair.sample(Cruise(0.5, speed=30.0), world)
    assert s["rgb_right"].shape == (32, 48, 3) and s["baseline_m"] == pytest.approx(0.12)
    with pytest.raises(RoadtwinError, match="exposure 0.05 s is longer than the frame period"):
        mount("camera", 30.0, exposure_s=0.05)


def striped_world():
    """The plane z = 0 painted with stripes across x (period 0.3 m) in closed form: what a blurred
    image of it looks like is known by rendering every instant."""
    def render(cameras):
        for cam in cameras:
            left = cam.left if isinstance(cam, StereoCamera) else cam
            out = []
            for c in ([left, cam.right] if isinstance(cam, StereoCamera) else [left]):
                depth, hit = plane_view(c)
                d, o = c.rays()
                with np.errstate(divide="ignore", invalid="ignore"):
                    x = o[0] - o[2] / d[..., 2] * d[..., 0]
                shade = np.where(hit, 0.5 + 0.4 * np.sin(2 * math.pi * np.nan_to_num(x) / 0.3), 0.9)
                out.append((depth, np.repeat(shade[..., None], 3, axis=2).astype(np.float32), hit))
            frame = SimpleNamespace(camera=left, depth=out[0][0], rgb=out[0][1], semantic=out[0][2].astype(np.uint8),
                                    instance=np.zeros(out[0][0].shape, np.int32),
                                    rgb_right=out[1][1] if len(out) > 1 else None)
            yield frame

    return SimpleNamespace(render=lambda cameras: list(render(cameras)), class_names=["background", "driving"])


@pytest.mark.parametrize("kind", ["camera", "stereo"])
def test_reprojected_motion_blur_matches_rendering_every_subframe(kind):
    """A camera looking sideways and down at striped ground passes it at 20 m/s: the near ground
    moves several pixels in the 8 ms exposure. Moving the middle sub-frame through its depth to every sub-frame's pose
    (one render) gives the image that rendering all sub-frames gives, to within a few DN where
    the blur changes pixels by tens of DN."""
    sideways = np.eye(4)
    sideways[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    down = np.eye(4)
    down[:3, :3] = [[math.cos(0.8), 0.0, math.sin(0.8)], [0.0, 1.0, 0.0], [-math.sin(0.8), 0.0, math.cos(0.8)]]
    ext = sideways @ down
    ext[:3, 3] = [0.0, 1.0, 1.5]
    world, state = striped_world(), Cruise(0.5, speed=20.0)
    shots = {}
    for blur in ("render", "reproject"):
        cam = mount(kind, 20.0, ext, width=96, height=64, max_subframes=9, read_noise=0.0, blur=blur)
        shots[blur] = cam.sample(state, world)
    sharp = mount(kind, 20.0, ext, width=96, height=64, exposure_s=0.0, read_noise=0.0).sample(state, world)
    assert shots["render"]["subframes"] == shots["reproject"]["subframes"] >= 5
    for eye in ("rgb", "rgb_right") if kind == "stereo" else ("rgb",):
        exact, fast = (shots[b][eye].astype(float) for b in ("render", "reproject"))
        blur_change = np.abs(exact - sharp[eye].astype(float)).mean()
        assert blur_change > 15.0, blur_change
        assert np.abs(exact - fast).mean() < 0.1 * blur_change, (np.abs(exact - fast).mean(), blur_change)
    with pytest.raises(RoadtwinError, match="blur must be reproject or render"):
        mount("camera", 10.0, blur="smear")


def test_the_rosette_scan_simulator_is_a_sensor_model_now():
    """Moved from roadtwin_lidar (issue 20): the LiDAR reconstructor's plugin keeps the ground
    truth and the scoring, the sensors plugin the scanner."""
    lidar = importlib.import_module("roadtwin_lidar")
    for name in ("simulate_scans", "RosetteScanner", "rosette_directions", "path_poses"):
        assert hasattr(rs, name) and name not in lidar.__all__
    d = rs.rosette_directions(2000, 0.0, 0.1, 70.4, 1180.0, 1180.0 * 0.618 * 1.3)
    assert np.degrees(np.arccos(d[:, 2])).max() <= 70.4 / 2 + 1e-6
