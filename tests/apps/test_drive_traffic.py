"""Other vehicles on the lanes (``apps/drive/traffic.py``): kinematic boxes that the drive's LiDAR
and cameras see, against closed forms: the slab distance to a box, where a vehicle driving a
straight lane at a known speed is at a known time, and its pixels in a camera looking at it."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from roadtwin_core.apps.drive.traffic import PALETTE, Traffic, Vehicle, ray_boxes
from roadtwin_core.apps.drive.world import World
from roadtwin_core.render import Camera, Frame, Intrinsics, Lane, RenderParams, look_from

pytest.importorskip("open3d")
HALF = np.array([2.25, 0.9, 0.75])
PALETTE_0 = PALETTE[0]


def yawed(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_ray_box_distances_and_normals_in_closed_form():
    boxes = [(np.array([10.0, 0.0, 0.75]), yawed(0.0), HALF), (np.array([0.0, 10.0, 0.75]), yawed(90.0), HALF)]
    o = np.zeros((4, 3)) + [0.0, 0.0, 0.75]
    d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [math.cos(0.1), math.sin(0.1), 0.0]])
    t, which, normal = ray_boxes(o, d, boxes)
    # the first box's rear face at x = 10 - 2.25; the second, turned 90 deg, shows its side: y = 10 - 2.25 too
    np.testing.assert_allclose(t[:2], [7.75, 7.75])
    np.testing.assert_array_equal(which, [0, 1, -1, 0])
    np.testing.assert_allclose(normal[:2], [[-1, 0, 0], [0, -1, 0]], atol=1e-12)
    assert math.isinf(t[2])
    assert t[3] == pytest.approx(7.75 / math.cos(0.1))       # 0.1 rad off the axis: still the rear face


class PlaneRenderer:
    """The plane z = 0 in closed form (grey road, class 1): what the town would render."""

    def prepare(self, mesh, params):
        return None

    def render(self, prepared, cameras, params):
        for cam in cameras:
            d, o = cam.rays()
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -o[2] / d[..., 2]
            hit = np.isfinite(t) & (t > 0)
            depth = np.where(hit, t * (d @ cam.rotation[:, 2]), 0.0).astype(np.float32)
            yield Frame(index=0, camera=cam, rgb=np.full(d.shape, 0.3, np.float32), depth=depth,
                        semantic=hit.astype(np.uint8), instance=np.zeros(depth.shape, np.int32))


def traffic_world() -> World:
    """A 200 m square of road (class 1) at z = 0, one car on lane x = 0 .. 100 m along y = 0,
    starting at x = 20 m, driving +x at 10 m/s."""
    v = np.array([[-100, -100, 0], [100, -100, 0], [100, 100, 0], [-100, 100, 0]], float)
    mesh = SimpleNamespace(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]]), classes=["background", "road"],
                           instances=[{"id": 3, "defect_id": "D1"}], face_class=np.array([1, 1]),
                           face_instance=np.array([0, 0]))
    world = World(mesh, PlaneRenderer(), RenderParams())
    lane = Lane("east", np.array([[0.0, 0.0], [100.0, 0.0]]))
    world.set_traffic(Traffic([Vehicle(lane, 20.0, 10.0, (0.6, 0.1, 0.1))], world.ground_z))
    return world


def test_lidar_sees_the_car_where_it_drives_at_the_samples_time():
    world = traffic_world()
    assert world.class_names == ["background", "road", "vehicle"] and world.instances == {3: "D1", 4: "vehicle_0"}
    origin, ahead = np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]])
    for t in (0.0, 1.5):
        world.time = t
        hit = world.cast(origin, ahead)
        rear = 20.0 + 10.0 * t - HALF[0]                          # the car's rear face, x
        assert hit["t"][0] == pytest.approx(rear, abs=1e-4) and hit["class_id"][0] == 2 and hit["instance"][0] == 4
    world.time = 0.0
    down = world.cast(np.array([[30.0, 0.0, 5.0]]), np.array([[0.0, 0.0, -1.0]]))   # behind the car at t = 0
    assert down["t"][0] == pytest.approx(5.0) and down["class_id"][0] == 1
    world.time = 1.0                                               # now the car is there: its roof, 1.5 m up
    down = world.cast(np.array([[30.0, 0.0, 5.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert down["t"][0] == pytest.approx(5.0 - 2 * HALF[2]) and down["class_id"][0] == 2


def test_cameras_draw_the_car_in_front_of_the_road():
    """A camera 2 m up at x = 0 looking along +x: the pixel of the car's rear-face centre shows the
    car (class, instance, z-depth of its rear face, its paint), the road below it stays road."""
    world = traffic_world()
    world.time = 1.0
    cam = Camera(Intrinsics.from_fov(160, 90, 60.0), look_from([0.0, 0.0, 2.0], 0.0, math.radians(-5.0)))
    frame = world.render([cam])[0]
    rear = np.array([[30.0 - HALF[0], 0.0, HALF[2]]])
    (u, v), z = cam.project(rear)[0][0], cam.project(rear)[1][0]
    u, v = int(round(u)), int(round(v))
    assert frame.semantic[v, u] == 2 and frame.instance[v, u] == 4
    assert frame.depth[v, u] == pytest.approx(z, rel=1e-3)
    assert frame.rgb[v, u, 0] > frame.rgb[v, u, 1] and frame.rgb[v, u, 0] != pytest.approx(0.3)
    assert frame.semantic[-1, u] == 1 and frame.depth[-1, u] < z   # the road just ahead of the camera


def test_vehicles_that_would_drive_through_the_ego_are_left_out():
    """Kinematic traffic neither brakes nor steers: on a straight road the ego plans 10 m/s for 20 s
    (200 m). A car 40 m ahead in its lane at 5 m/s is caught after about 7 s; a car stopped at the
    end of a lane that ends on the route (its centre 67.75 m in) is reached after about 6 s; both
    are left out. A car 30 m ahead at the
    ego's speed, and one in the next lane (3.5 m over) at any speed, never come near it: kept."""
    from roadtwin_core.apps.drive.route import Route, constant_speed
    from roadtwin_core.apps.drive.traffic import clear_of_ego

    def lane(y, length=300.0, x0=0.0):
        return Lane(f"y{y}_x{x0}", np.column_stack([np.linspace(x0, x0 + length, 31), np.full(31, y)]))

    route = Route(np.array([[0.0, 0.0], [200.0, 0.0]]), "test")
    cars = [Vehicle(lane(0.0), 40.0, 5.0, PALETTE_0), Vehicle(lane(0.0, 60.0, x0=10.0), 60.0, 0.0, PALETTE_0),
            Vehicle(lane(0.0), 30.0, 10.0, PALETTE_0), Vehicle(lane(3.5), 0.0, 25.0, PALETTE_0)]
    kept, out = clear_of_ego(Traffic(cars, lambda xy: 0.0), route, constant_speed(36.0), (1.8, 4.5))
    assert out == [0, 1] and kept.vehicles == cars[2:]
    # the ego plan and the kept cars, sampled independently: always more than 0.5 m apart bumper to bumper
    for t in np.arange(0.0, 20.0, 0.01):
        ego_x = 10.0 * t
        for c, _, half in kept.boxes(t):
            gap_along = abs(c[0] - ego_x) - half[0] - 2.25
            gap_across = abs(c[1]) - half[1] - 0.9
            assert max(gap_along, gap_across) > 0.5
