"""The camera model and ego-lane labels as device kernels (``plugins/roadtwin_warp_render/post*.py``,
what ``roadtwin render --device cuda`` runs), run here on warp's CPU device and checked against
the numpy camera model and ego lane (``roadtwin_core.render.randomize`` / ``ego_lane``), which
stay the CPU path's reference:

- noise: per intensity, the mean and std of the 8-bit output match numpy's Poisson + Gaussian
  model (other random numbers, same statistics); same seed, same bytes;
- auto-exposure: the device's scale is numpy's bisection's (after vignetting);
- motion blur, vignetting, white balance, tone curve without noise: the numpy model's image
  within a level or two (bilinear taps: cv2 interpolates with 1/32 px weights);
- ego lane: a plane seen through the renderer, a curved lane: the device labels equal
  ``ego_lane_mask`` through the class map's tables up to a tiny boundary fraction;
- end to end (slow): a composed sample town rendered with the device path forced vs the CPU path.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

wp = pytest.importorskip("warp")
post = pytest.importorskip("roadtwin_warp_render.post")
rc = pytest.importorskip("roadtwin_warp_render.raycast")

from roadtwin_core.render import Camera, Intrinsics, look_from, to_srgb8  # noqa: E402
from roadtwin_core.render.classmap import load_class_map  # noqa: E402
from roadtwin_core.render.ego_lane import ego_lane_mask, lane_coordinates  # noqa: E402
from roadtwin_core.render.randomize import (ImageEffects, auto_exposure, forward_flow, motion_blur,  # noqa: E402
                                            sensor_noise, vignetting)

W, H = 96, 64


def survey_camera(w=W, h=H) -> Camera:
    return Camera(Intrinsics.from_fov(w, h, 60.0), look_from((0.0, 0.0, 1.8), 0.0, np.radians(-20.0)))


def stand_in_gbuffer(rgb: np.ndarray, depth: np.ndarray, device="cpu"):
    """What the finisher reads of a G-buffer, from arrays (every pixel a hit of class 1)."""
    n = rgb.shape[0] * rgb.shape[1]
    a = lambda x, t: wp.array(np.ascontiguousarray(x).reshape(n, -1).squeeze(), dtype=t, device=device)  # noqa: E731
    return SimpleNamespace(rgb=a(rgb.astype(np.float32), wp.vec3), depth=a(depth.astype(np.float32), float),
                           dist=a(depth.astype(np.float32), float), face=a(np.zeros(n, np.int32), wp.int32),
                           cls=a(np.ones(n, np.int32), wp.int32), inst=a(np.zeros(n, np.int32), wp.int32))


def device_image(rgb, depth, camera, effects, batch=1, device="cpu"):
    fin = post.DeviceFinisher(rgb.shape[1], rgb.shape[0], batch, device)
    k = camera.intrinsics
    cam = rc.make_cam(k.fx, k.fy, k.cx, k.cy, k.width, k.height, camera.cam_to_world)
    gb = stand_in_gbuffer(rgb, depth, device)
    sensors = []
    for slot in range(batch):
        sensors.append(post.make_sensor(effects, camera))
        fin.frame(slot, cam, gb, sensors[-1], effects.blur_px if effects else 0.0,
                  {"label_distance": 1e9, "background": 0})
    return fin.finish(cam, sensors)


def test_noise_statistics_match_the_numpy_model(device="cpu"):
    levels = np.array([0.01, 0.03, 0.08, 0.2, 0.5], np.float32)
    rgb = np.repeat(levels, W * H // len(levels) + 1)[:W * H].reshape(H, W, 1).repeat(3, axis=2)
    depth = np.zeros((H, W), np.float32)
    fx = ImageEffects(gain=1 / 600, read_noise=0.004, noise_seed=(7, 3, 1))
    out = device_image(rgb, depth, survey_camera(), fx, device=device)["rgb8"][0].astype(float)
    ref = to_srgb8(sensor_noise(rgb, fx.gain, fx.read_noise, np.random.default_rng(list(fx.noise_seed)))).astype(float)
    for v in levels:
        m = rgb[..., 0] == v
        assert abs(out[m].mean() - ref[m].mean()) < 0.35, v
        assert out[m].std() == pytest.approx(ref[m].std(), rel=0.08, abs=0.05), v
    again = device_image(rgb, depth, survey_camera(), fx, device=device)["rgb8"][0]
    np.testing.assert_array_equal(again, out.astype(np.uint8))          # same seed, same bytes
    other = device_image(rgb, depth, survey_camera(), replace(fx, noise_seed=(7, 4, 1)), device=device)["rgb8"][0]
    assert (other != again).mean() > 0.3                                 # another frame, other noise


def scene_like_image(seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W] / np.array([H, W]).reshape(2, 1, 1)
    base = 0.05 + 0.4 * yy[..., None] * np.array([1.0, 0.9, 0.8]) + 0.2 * (xx[..., None] > 0.5)
    return (base + 0.03 * rng.random((H, W, 3))).astype(np.float32)


def test_auto_exposure_is_the_bisections_scale(device="cpu"):
    rgb = scene_like_image()
    cam = survey_camera()
    fx = ImageEffects(vignetting=0.6, target_luminance=0.21)
    got = device_image(rgb, np.zeros((H, W), np.float32), cam, fx, device=device)["exposure_scale"][0]
    want = auto_exposure(rgb * vignetting(cam, 0.6)[..., None], 0.21)
    assert got == pytest.approx(want, rel=2e-4)


def road_depth() -> np.ndarray:
    """z-depth of a road below the horizon (3-14 m), sky above (0: no motion)."""
    rows = np.arange(H, dtype=float)[:, None]
    return np.repeat(np.where(rows > H // 2, 4.0 + 10.0 / np.maximum(rows - H // 2, 1.0), 0.0), W, axis=1)


def exposure_integral(img: np.ndarray, flow: np.ndarray, taps: int = 64) -> np.ndarray:
    """The image averaged over 64 points of each pixel's motion: the integral both models approximate."""
    import cv2

    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    acc = np.zeros_like(img)
    for t in np.linspace(-0.5, 0.5, taps, dtype=np.float32):
        acc += cv2.remap(img, gx + t * flow[..., 0], gy + t * flow[..., 1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)
    return acc / taps


@pytest.mark.parametrize("travel_m", [0.3, 0.6])
def test_motion_blur_is_as_close_to_the_exposure_integral_as_the_numpy_model(travel_m):
    yy, xx = np.mgrid[0:H, 0:W]
    checker = (0.05 + 0.5 * (((yy // 3) + (xx // 3)) % 2))[..., None].repeat(3, axis=2).astype(np.float32)
    cam, depth = survey_camera(), road_depth().astype(np.float32)
    flow = forward_flow(cam, depth, travel_m)
    assert np.abs(flow).max() > 3.0                                  # pixels move several pixels
    truth = to_srgb8(exposure_integral(checker, flow)).astype(int)
    numpy_model = to_srgb8(motion_blur(checker, flow)).astype(int)
    got = device_image(checker, depth, cam, ImageEffects(travel_m=travel_m))["rgb8"][0].astype(int)
    err, err_numpy = np.abs(got - truth), np.abs(numpy_model - truth)
    assert err.mean() <= 1.25 * err_numpy.mean() + 0.3, (err.mean(), err_numpy.mean())
    assert np.percentile(err, 99) <= np.percentile(err_numpy, 99) + 3
    assert np.abs(got - to_srgb8(checker).astype(int)).mean() > 5 * err.mean()   # it did blur


def test_vignetting_white_balance_saturation_and_tone_match_the_numpy_model():
    rgb, cam = scene_like_image(1), survey_camera()
    fx = ImageEffects(vignetting=0.8, exposure=1.3, wb_gains=(1.05, 1.0, 0.95), saturation=1.2)
    got = device_image(rgb, np.zeros((H, W), np.float32), cam, fx)["rgb8"][0].astype(int)
    x = rgb * vignetting(cam, fx.vignetting)[..., None] * fx.exposure * np.asarray(fx.wb_gains, np.float32)
    y = (x @ np.array([0.2126, 0.7152, 0.0722], np.float32))[..., None]
    want = to_srgb8(y + fx.saturation * (x - y)).astype(int)
    assert np.abs(got - want).max() <= 1 and (got != want).mean() < 0.01


def plane_with_lane():
    """A 60 x 40 m plane (class 1) rendered from the survey pose, and a curved lane centreline."""
    v = np.array([[-5, -20, 0], [55, -20, 0], [55, 20, 0], [-5, 20, 0]], float)
    rs = rc.RaycastScene(v, np.array([[0, 1, 2], [0, 2, 3]]), [1, 1], [0, 0], device="cpu")
    s = np.linspace(0.0, 50.0, 60)
    lane = np.column_stack([s - 2.0, 0.004 * s ** 2 - 0.3])        # bends left, starts behind the camera
    return rs, lane


def test_ego_lane_labels_equal_the_numpy_ego_lane():
    rs, lane = plane_with_lane()
    camera = Camera(Intrinsics.from_fov(160, 100, 60.0), look_from((0.0, 0.0, 1.8), 0.05, np.radians(-15.0)))
    k = camera.intrinsics
    cam = rc.make_cam(k.fx, k.fy, k.cx, k.cy, k.width, k.height, camera.cam_to_world)
    gb = rs.buffer(k.width, k.height)
    rs.gbuffer(cam, gb)
    cmap = load_class_map("road_defects_br")
    names = ["background", "driving"]
    plain, inside = cmap.lookup_tables(names)
    s_cam = float(lane_coordinates(camera.position[None, :2], lane)[0][0])
    fin = post.DeviceFinisher(k.width, k.height, 1, "cpu")
    gb.rgb.zero_()
    fin.frame(0, cam, gb, post.make_sensor(None, camera), 0.0,
              {"label_distance": 150.0, "background": 0, "plain": np.asarray(plain, np.uint8),
               "inside": np.asarray(inside, np.uint8), "lane": lane, "half_width": 1.75, "s_cam": s_cam})
    got = fin.finish(cam, [post.make_sensor(None, camera)])["labels"][0]
    g = gb.numpy(("depth", "cls"))
    ego = ego_lane_mask(camera, g["depth"], lane, 3.5, surface=(g["depth"] > 0) & (g["cls"] != 0))
    want = cmap.apply(g["cls"].astype(np.uint8), names, ego)
    ego_id = list(cmap.classes).index("ego_lane")
    assert (want == ego_id).mean() > 0.15                  # the lane fills a good part of the view
    assert (got != want).mean() < 2e-3, (got != want).mean()


@pytest.mark.slow
def test_a_composed_town_finished_on_the_device_matches_the_cpu_path(tmp_path, monkeypatch):
    """The sample town, survey rig, randomized, class-mapped: labels equal but at a tiny
    boundary fraction, images alike (same look and exposure; other noise), JPEG bytes written."""
    from PIL import Image

    import roadtwin_core.apps.render.frame_sink as frame_sink
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.apps.render import RenderOptions, run_render

    repo = Path(__file__).resolve().parents[2]
    town = compose(repo / "stages/town.usda", tmp_path / "town", preview=False, executor="serial").town
    o = RenderOptions(frames=3, rig="survey", size="256x160", views="defects:0.6", randomize=True,
                      classmap="builtin:road_defects_br", formats="mmseg", seed=3, executor="serial", device="cpu")
    run_render(town, tmp_path / "cpu", o)
    monkeypatch.setattr(frame_sink, "finish_on_device", lambda ctx, jobs, device: True)
    run_render(town, tmp_path / "dev", o)
    for i in range(3):
        ann, img = f"mmseg/ann_dir/train/{i:06d}.png", f"mmseg/img_dir/train/{i:06d}.jpg"
        a, b = (np.asarray(Image.open(tmp_path / d / ann)) for d in ("cpu", "dev"))
        assert (a != b).mean() < 1e-3 and (a == 1).mean() > 0.1
        x, y = (np.asarray(Image.open(tmp_path / d / img), dtype=float) for d in ("cpu", "dev"))
        assert abs(x.mean() - y.mean()) < 1.0 and np.abs(x - y).mean() < 8.0


@pytest.mark.gpu
def test_the_kernels_on_cuda():
    """The same checks on a CUDA device (where ``roadtwin render --device cuda`` runs them)."""
    if not wp.is_cuda_available():
        pytest.skip("no CUDA device")
    test_noise_statistics_match_the_numpy_model("cuda")
    test_auto_exposure_is_the_bisections_scale("cuda")
