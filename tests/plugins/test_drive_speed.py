"""The drive's CPU speed-ups must not change what it renders (issue 20, bench/drive.py):

- a frame shaded in bands of rows on a thread pool has the bytes of one launch;
- shadow rays answered by Embree (open3d backend) shade the same pixels as warp's own shadow
  rays, and both match the closed-form shadow of a box on the ground;
- the exposure's mean, summed in place, has the bytes of ``np.mean(np.stack(...), axis=0)``.
"""
from __future__ import annotations

import numpy as np
import pytest

rc = pytest.importorskip("roadtwin_warp_render.raycast")
pytest.importorskip("open3d")

W, H, F = 64, 48, 40.0
BOX_LO, BOX_HI = np.array([-0.5, 3.5, 0.0]), np.array([0.5, 4.5, 1.0])
SUN_EL, SUN_AZ = 45.0, 120.0


def box_scene():
    """A 20 x 20 m ground quad (z = 0) and a 1 m cube standing on it, 4 m ahead of the camera."""
    g = np.array([[-10, -2, 0], [10, -2, 0], [10, 18, 0], [-10, 18, 0]], float)
    faces = [[0, 1, 2], [0, 2, 3]]
    corners = np.array([[x, y, z] for z in (BOX_LO[2], BOX_HI[2]) for y in (BOX_LO[1], BOX_HI[1])
                        for x in (BOX_LO[0], BOX_HI[0])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    for a, b, c, d in quads:
        faces += [[4 + a, 4 + b, 4 + c], [4 + a, 4 + c, 4 + d]]
    v = np.vstack([g, corners])
    n = len(faces)
    return rc.RaycastScene(v, np.array(faces), [1] * n, [0] * n, device="cpu")


def camera():
    """1.5 m up, looking along +y pitched 20 degrees down (OpenCV axes: x right, y down, z forward)."""
    p = np.radians(-20.0)
    fwd, right = np.array([0.0, np.cos(p), np.sin(p)]), np.array([1.0, 0.0, 0.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(fwd, right), fwd, (0.0, 0.0, 1.5)
    return rc.make_cam(F, F, (W - 1) / 2, (H - 1) / 2, W, H, m), m


def shade(rs, cam, shadows: bool, embree: bool, threads: int, monkeypatch):
    monkeypatch.setattr(rc, "CPU_THREADS", threads)
    rs._o3d = None
    if embree:
        rs.enable_open3d()
    gb = rs.buffer(W, H)
    rs.gbuffer(cam, gb)
    light = rc.make_light(rc.light_preset("clear", sun_elevation_deg=SUN_EL, sun_azimuth_deg=SUN_AZ,
                                          shadows=shadows))
    rs.shade(cam, light, gb)
    return gb.numpy(("rgb", "dist", "face"))


def box_shadow(m: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Closed form: the ground point a pixel sees is in shadow when the ray from it to the sun
    passes through the box (slab test)."""
    jj, ii = np.mgrid[0:H, 0:W].astype(float)
    d = np.stack([(ii - (W - 1) / 2) / F, (jj - (H - 1) / 2) / F, np.ones_like(ii)], -1) @ m[:3, :3].T
    p = m[:3, 3] + d / np.linalg.norm(d, axis=-1, keepdims=True) * dist[..., None]
    el, az = np.radians(SUN_EL), np.radians(SUN_AZ)
    s = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    with np.errstate(divide="ignore"):
        t0, t1 = (BOX_LO - p) / s, (BOX_HI - p) / s
    near, far = np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)
    return (far > np.maximum(near, 0.0)) & (p[..., 2] < 1e-3)


def test_banded_threaded_shading_and_embree_shadows_keep_the_image(monkeypatch):
    rs = box_scene()
    cam, m = camera()
    one = shade(rs, cam, True, False, 1, monkeypatch)
    banded = shade(rs, cam, True, False, 3, monkeypatch)
    assert np.array_equal(one["rgb"], banded["rgb"])
    embree = shade(rs, cam, True, True, 3, monkeypatch)
    lit = shade(rs, cam, False, True, 3, monkeypatch)
    truth = box_shadow(m, one["dist"])
    assert 30 < truth.sum() < 0.5 * W * H          # the box casts a real shadow into the view
    for img in (one, embree):
        shadowed = (img["rgb"] < lit["rgb"] - 1e-4).any(-1) & (one["face"] < 2)     # ground faces 0, 1
        edge = truth ^ shadowed
        assert edge.sum() <= 0.05 * truth.sum(), (edge.sum(), truth.sum())
    assert (embree["rgb"] != one["rgb"]).any(-1).sum() <= 0.01 * W * H


def test_exposure_mean_has_the_bytes_of_numpy_mean():
    cam_mod = pytest.importorskip("roadtwin_sensors.camera")
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 7):
        imgs = [(rng.random((9, 11, 3)) * 4).astype(np.float32) for _ in range(n)]
        assert np.array_equal(cam_mod.exposure_mean(imgs), np.mean(np.stack(imgs), axis=0))


def test_reprojected_blur_on_threads_keeps_its_bytes(monkeypatch):
    """The sub-frames are moved on a thread pool into buffers kept across frames and summed in
    their order: one thread or eight, a first or a later call (buffers reused after another
    frame's), the bytes are the same; the mean of unmoved sub-frames is the image itself."""
    from concurrent.futures import ThreadPoolExecutor

    from roadtwin_core.render import Camera, Intrinsics, look_from

    cam_mod = pytest.importorskip("roadtwin_sensors.camera")
    rng = np.random.default_rng(3)
    k = Intrinsics.from_fov(160, 90, 80.0)
    rgb = rng.random((90, 160, 3), dtype=np.float32)
    depth = rng.random((90, 160), dtype=np.float32) * 20 + 2
    cams = [Camera(k, look_from((0.04 * i, 0.0, 1.5), 0.002 * i, -0.2)) for i in range(7)]
    first = cam_mod.reproject_blur(rgb, depth, cams[3], cams)
    other = cam_mod.reproject_blur(rgb[::-1].copy(), depth, cams[1], cams[:5])
    again = cam_mod.reproject_blur(rgb, depth, cams[3], cams)
    monkeypatch.setitem(cam_mod._BLUR_STATE, "pool", ThreadPoolExecutor(1))
    one_thread = cam_mod.reproject_blur(rgb, depth, cams[3], cams)
    assert np.array_equal(first, again) and np.array_equal(first, one_thread)
    assert not np.array_equal(first, other)
    still = cam_mod.reproject_blur(rgb, depth, cams[3], [cams[3]] * 3)
    np.testing.assert_allclose(still, rgb, rtol=1e-6)


def test_develop_in_bands_is_the_one_pass_camera_model():
    """The camera's development (tone curve, read noise drawn in one piece, rounding) runs in
    bands of rows on threads: its bytes are the one-pass formula's, frame after frame."""
    from types import SimpleNamespace

    from roadtwin_core.render import to_srgb8

    cam_mod = pytest.importorskip("roadtwin_sensors.camera")
    lin = np.random.default_rng(4).random((45, 80, 3), dtype=np.float32) * 2
    sensor = SimpleNamespace(params=SimpleNamespace(read_noise=1.5), rng=np.random.default_rng(9))
    ref_rng = np.random.default_rng(9)
    for _ in range(2):
        want = to_srgb8(lin).astype(np.float32) + ref_rng.normal(0.0, 1.5, lin.shape).astype(np.float32)
        want = np.clip(np.round(want), 0, 255).astype(np.uint8)
        np.testing.assert_array_equal(cam_mod.CameraSensor._develop(sensor, lin), want)
