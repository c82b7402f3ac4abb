"""Fake plugins for tests without a GPU stack (as httpx has a fake transport): they register
through the plugin manager like any backend and produce outputs known in closed form, so the
orchestration around them (sweeps, recommendations, files) is tested where warp is absent.

``FakePhysics``: every vehicle's IMU reads constant offsets from rest that depend only on its
speed v (m/s) and on how deep the road mesh goes below zero (``depth`` = -min z of its
vertices, 0 on a flat road with its defects filled in)::

    az = g + K_AZ * v * depth,   wx = K_WX * depth / v,   wy = wz = 0

so the vibration degree of a crossing against its twin run is, at every sample,
``g = depth * sqrt((K_WX / v)^2 + 0.1 (K_AZ v)^2)`` and the Wk-weighted aw of a constant is 0.

``FakeRenderer``: sees the world as the plane z = 0 (whatever the scene holds): a pixel whose ray
meets the plane in front of the camera gets class ``driving``, z-depth from the ray-plane
intersection, normal (0, 0, 1) in camera axes and grey ``rgb = GROUND``; other pixels are sky
(class 0, depth 0, ``rgb = SKY``). Stereo cameras get the right view and ``f * B / Z``.
"""
from __future__ import annotations

import numpy as np

from roadtwin_core import PluginManager, RendererBase, hookimpl
from roadtwin_core.render import Frame, RenderParams, StereoCamera
from roadtwin_core.vehicle import GRAVITY, SimParams, Traces

K_AZ = 2.0
K_WX = 1.5


def fake_g(depth: float, speed_ms: float) -> float:
    """The closed form of the vibration degree a FakePhysics crossing produces."""
    return depth * float(np.sqrt((K_WX / speed_ms) ** 2 + 0.1 * (K_AZ * speed_ms) ** 2))


class FakePhysics:
    name = "fake"
    description = "closed-form IMU traces for tests (no simulation)"
    Params = SimParams

    def __init__(self) -> None:
        self.calls = 0

    def simulate(self, road_mesh, vehicles, params: SimParams | None = None) -> Traces:
        params = params or SimParams()
        self.calls += 1
        depth = max(0.0, -float(np.min(np.asarray(road_mesh.vertices)[:, 2])))
        every = max(1, int(round(1.0 / (params.imu_rate_hz * params.dt_s))))
        dt_imu = every * params.dt_s
        valid = np.array([int(round(v.duration / params.dt_s)) // every for v in vehicles])
        n, T = len(vehicles), int(valid.max())
        t = (np.arange(T) + 1) * dt_imu
        acc = np.full((n, T, 3), np.nan)
        gyro = np.full((n, T, 3), np.nan)
        for i, v in enumerate(vehicles):
            k = valid[i]
            acc[i, :k] = [0.0, 0.0, GRAVITY + K_AZ * v.speed * depth]
            gyro[i, :k] = [K_WX * depth / v.speed, 0.0, 0.0]
        nan4 = np.full((n, T, 4), np.nan)
        return Traces(t=t, acc=acc, gyro=gyro, pose=np.full((n, T, 6), np.nan), wheel_z=nan4, tire_f=nan4.copy(),
                      susp=nan4.copy(), valid=valid, off_road=np.zeros(n, dtype=bool),
                      meta={"backend": self.name, "device": "cpu", "wall_s": 1e-3,
                            "sim_s": float(sum(v.duration for v in vehicles)), "setup_s": 0.0, "dt": params.dt_s,
                            "imu_dt": dt_imu, "mode": "full", "triangles": int(len(road_mesh.faces))})


GROUND, SKY = 0.25, 0.8


def plane_view(camera) -> tuple[np.ndarray, np.ndarray]:
    """z-depth (H, W) of the plane z = 0 seen by ``camera`` (0 = sky) and the hit mask."""
    d, o = camera.rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[..., 2]
    hit = np.isfinite(t) & (t > 0)
    zdepth = np.where(hit, t * (d @ camera.rotation[:, 2]), 0.0)
    return zdepth.astype(np.float32), hit


class FakeRenderer(RendererBase):
    name = "fake"
    description = "the plane z = 0 in closed form, for tests (no ray tracing)"
    Params = RenderParams

    def __init__(self) -> None:
        self.frames = 0

    def render(self, scene, cameras, params=None, *, look=None):
        driving = list(scene.classes).index("driving")
        for i, cam in enumerate(cameras):
            left = cam.left if isinstance(cam, StereoCamera) else cam
            depth, hit = plane_view(left)
            rgb = np.where(hit[..., None], GROUND, SKY).astype(np.float32) * np.ones(3, np.float32)
            normal = np.where(hit[..., None], left.rotation.T @ np.array([0.0, 0.0, 1.0]), 0.0).astype(np.float32)
            frame = Frame(index=i, camera=left, rgb=rgb, depth=depth, normal=normal,
                          semantic=np.where(hit, driving, 0).astype(np.uint8),
                          instance=np.zeros(depth.shape, np.int32))
            if isinstance(cam, StereoCamera):
                k = left.intrinsics
                frame.right_camera = cam.right
                frame.rgb_right = rgb.copy()
                with np.errstate(divide="ignore"):
                    frame.disparity = np.where(hit, k.fx * cam.baseline / np.where(hit, depth, 1), 0).astype(np.float32)
                frame.occluded = np.zeros(depth.shape, bool)
            self.frames += 1
            yield frame


class _FakePlugin:
    def __init__(self, backend: FakePhysics, renderer: FakeRenderer) -> None:
        self.backend, self.renderer = backend, renderer

    @hookimpl
    def roadtwin_register_physics_backends(self, register):
        register(self.backend)

    @hookimpl
    def roadtwin_register_renderers(self, register):
        register(self.renderer)


def fake_plugin_manager(backend: FakePhysics | None = None, renderer: FakeRenderer | None = None) -> PluginManager:
    """A plugin manager holding only the fakes (no entry points)."""
    pm = PluginManager(load_entry_points=False)
    pm.register(_FakePlugin(backend or FakePhysics(), renderer or FakeRenderer()), name="fakes")
    return pm
