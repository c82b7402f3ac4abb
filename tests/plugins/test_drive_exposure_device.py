"""A drive camera developed on the renderer's device (``roadtwin_warp_render/exposure.py``) is the
host's camera model (``roadtwin_sensors.camera``: ``reproject_blur`` then the tone curve and read
noise), run here as warp kernels on the CPU device:

- without noise, its image is the host model's up to the sub-pixel rounding of cv2.remap's
  1/32-pixel bilinear weights (a few DN at most, a tiny mean);
- its read noise is Gaussian with the asked sigma (the rounding adds 1/12 DN^2), zero mean;
  the same seed gives the same bytes, another seed other noise.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

wp = pytest.importorskip("warp")
rc = pytest.importorskip("roadtwin_warp_render.raycast")
exposure = pytest.importorskip("roadtwin_warp_render.exposure")
cam_mod = pytest.importorskip("roadtwin_sensors.camera")

from roadtwin_core.render import Camera, Intrinsics, look_from, to_srgb8  # noqa: E402
from roadtwin_core.warp_runtime import start_warp  # noqa: E402

W, H = 96, 60


def smooth_scene():
    """A striped linear image (the blur shows) over a road-like depth ramp with sky on top."""
    jj, ii = np.mgrid[0:H, 0:W].astype(np.float32)
    rgb = np.stack([0.3 + 0.25 * np.sin(ii / 2.5), 0.4 + 0.2 * np.cos(jj / 3.0), 0.2 + 0.002 * ii * jj / 10], -1)
    depth = np.where(jj > 12, 60.0 / np.maximum(jj - 10.0, 1.0), 0.0).astype(np.float32)
    return rgb.astype(np.float32), depth


def on_device(rgb, depth, mid: Camera, cams: list[Camera], read_noise: float = 0.0, seed: int = 1) -> np.ndarray:
    start_warp()
    k = mid.intrinsics
    gb = SimpleNamespace(rgb=wp.array(rgb.reshape(-1, 3), dtype=wp.vec3, device="cpu"),
                         depth=wp.array(depth.reshape(-1), dtype=float, device="cpu"))
    cam = rc.make_cam(k.fx, k.fy, k.cx, k.cy, k.width, k.height, mid.cam_to_world)
    return exposure.develop_exposure(gb, cam, mid.cam_to_world, [c.cam_to_world for c in cams], cam_mod.FAR_M,
                                     read_noise, seed)


def sub_frames(n: int = 7) -> list[Camera]:
    """A camera driving forward 4 cm and yawing 0.3 degrees a sub-frame (a car over a pothole)."""
    k = Intrinsics.from_fov(W, H, 80.0)
    return [Camera(k, look_from((0.0, 0.04 * i, 1.5), np.pi / 2 + np.radians(0.3) * i, -0.25)) for i in range(n)]


def test_device_exposure_is_the_host_blur_and_tone_curve():
    rgb, depth = smooth_scene()
    cams = sub_frames()
    mid = cams[3]
    host = to_srgb8(cam_mod.reproject_blur(rgb, depth, mid, cams)).astype(int)
    dev = on_device(rgb, depth, mid, cams).astype(int)
    diff = np.abs(dev - host)
    assert diff.max() <= 2 and diff.mean() < 0.1, (diff.max(), diff.mean())
    sharp = to_srgb8(rgb).astype(int)
    assert np.abs(host - sharp).mean() > 5 * diff.mean() + 0.5       # the blur is there, and the same
    still = on_device(rgb, depth, mid, [mid] * 3)
    np.testing.assert_array_equal(still, to_srgb8(rgb))               # unmoved sub-frames: the image itself


def test_device_read_noise_has_the_asked_sigma_and_follows_the_seed():
    rgb = np.full((H, W, 3), 0.3, np.float32)
    depth = np.full((H, W), 5.0, np.float32)
    mid = sub_frames(1)[0]
    clean = to_srgb8(rgb).astype(float)
    a = on_device(rgb, depth, mid, [mid], read_noise=2.0, seed=5)
    noise = a.astype(float) - clean
    assert abs(noise.mean()) < 0.05
    assert np.std(noise) == pytest.approx(np.sqrt(2.0**2 + 1 / 12), rel=0.03)
    np.testing.assert_array_equal(a, on_device(rgb, depth, mid, [mid], read_noise=2.0, seed=5))
    assert (a != on_device(rgb, depth, mid, [mid], read_noise=2.0, seed=6)).mean() > 0.5
