"""Cameras (mono and a rectified stereo pair) rendered through the renderer the drive uses.

Exposure-time motion blur from the body's real motion: the frame is the mean of sub-frames
rendered at the camera's poses across the exposure (stamped at its middle), as many as the
image moves pixels during it (the centre ray's and the image corners' motion, at most
``max_subframes``); labels, depth and instance ids are the middle sub-frame's (odd counts).
Sensor noise: Gaussian read noise on the tone-mapped 8-bit image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import RoadtwinError, field
from roadtwin_core.render import Camera, Intrinsics, StereoCamera, to_srgb8

from ._mount import OPTICAL_IN_LINK


@dataclass
class CameraParams:
    width: int = field(640, lo=8, hi=8192, doc="image width, px")
    height: int = field(360, lo=8, hi=8192, doc="image height, px")
    hfov_deg: float = field(90.0, lo=1.0, hi=179.0, doc="horizontal field of view, degrees")
    exposure_s: float = field(0.008, lo=0.0, hi=0.1, doc="exposure time, s (0: no motion blur)")
    max_subframes: int = field(7, lo=1, hi=31, doc="most sub-frames averaged for motion blur")
    read_noise: float = field(1.0, lo=0.0, hi=50.0, doc="Gaussian noise on the 8-bit image, DN (1 sigma)")
    baseline_m: float = field(0.12, lo=0.01, hi=5.0, doc="stereo baseline, m (stereo only)")
    seed: int = field(0, lo=0, doc="noise seed (combined with the sensor's name)")


class CameraSensor:
    kind = "camera"
    message = "image"

    def __init__(self, sensor_id, rate_hz, extrinsic, params: CameraParams, stereo: bool = False) -> None:
        self.id, self.rate_hz, self.extrinsic, self.params = sensor_id, float(rate_hz), np.asarray(extrinsic), params
        if params.exposure_s > 1.0 / self.rate_hz:
            raise RoadtwinError(f"sensor {sensor_id}: exposure {params.exposure_s} s is longer than the frame period "
                                f"{1.0 / self.rate_hz:.4f} s")
        self.stereo = stereo
        self.message = "stereo" if stereo else "image"
        self.intrinsics = Intrinsics.from_fov(int(params.width), int(params.height), params.hfov_deg)
        self.optical = np.eye(4)                    # optical frame in the body
        self.optical[:3, :3] = self.extrinsic[:3, :3] @ OPTICAL_IN_LINK
        self.optical[:3, 3] = self.extrinsic[:3, 3]
        self.rng = np.random.default_rng([params.seed, *sensor_id.encode()])

    def camera_at(self, state, t: float) -> Camera:
        return Camera(self.intrinsics, state.pose_at(t) @ self.optical)

    def _subframes(self, state) -> np.ndarray:
        p = self.params
        if p.exposure_s <= 0:
            return np.array([state.t])
        k = self.intrinsics
        a, b = self.camera_at(state, state.t - p.exposure_s / 2), self.camera_at(state, state.t + p.exposure_s / 2)
        # image motion of points 10 m out along the centre and corner rays
        rays = np.array([[0, 0, 1], [-k.cx / k.fx, -k.cy / k.fy, 1], [k.cx / k.fx, k.cy / k.fy, 1]], float)
        pts = a.position + 10.0 * (rays / np.linalg.norm(rays, axis=1, keepdims=True)) @ a.rotation.T
        ua, _ = a.project(pts)
        ub, _ = b.project(pts)
        move = float(np.nanmax(np.linalg.norm(ub - ua, axis=1)))
        n = int(min(p.max_subframes, max(1, math.ceil(move / 0.5) + 1)))
        n += (n + 1) % 2                               # odd: a middle sub-frame for the labels
        n = min(n, p.max_subframes if p.max_subframes % 2 else p.max_subframes - 1) or 1
        return state.t + (np.linspace(-0.5, 0.5, n) if n > 1 else np.zeros(1)) * p.exposure_s

    def sample(self, state, world) -> dict:
        p = self.params
        times = self._subframes(state)
        cams = [self.camera_at(state, t) for t in times]
        views = [StereoCamera(c, p.baseline_m) for c in cams] if self.stereo else cams
        frames = list(world.render(views))
        mid = frames[len(frames) // 2]
        out = {"t": state.t, "intrinsics": self.intrinsics, "subframes": len(frames), "exposure_s": p.exposure_s,
               "cam_to_world": mid.camera.cam_to_world, "semantic": mid.semantic, "instance": mid.instance,
               "depth": mid.depth}
        out["rgb"] = self._develop([f.rgb for f in frames])
        if self.stereo:
            out["rgb_right"] = self._develop([f.rgb_right for f in frames])
            out["baseline_m"] = p.baseline_m
        return out

    def _develop(self, rgbs) -> np.ndarray:
        img = to_srgb8(np.mean(np.stack(rgbs), axis=0)).astype(np.float32)
        if self.params.read_noise > 0:
            img += self.rng.normal(0.0, self.params.read_noise, img.shape).astype(np.float32)
        return np.clip(np.round(img), 0, 255).astype(np.uint8)


class MonoCamera:
    name = "camera"
    description = "pinhole camera through the drive's renderer: exposure-time motion blur from the body's motion, read noise, labels/depth/instances"
    Params = CameraParams
    message = "image"

    def create(self, sensor_id, rate_hz, extrinsic, params):
        return CameraSensor(sensor_id, rate_hz, extrinsic, params)


class StereoPair:
    name = "stereo"
    description = "rectified stereo pair (left mounted, right baseline_m along its x axis), motion blur like camera"
    Params = CameraParams
    message = "stereo"

    def create(self, sensor_id, rate_hz, extrinsic, params):
        return CameraSensor(sensor_id, rate_hz, extrinsic, params, stereo=True)
