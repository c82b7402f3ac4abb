"""Domain randomization and the camera model: determinism, draw ranges, and each image effect
against its physical model (noise variance, cos^4 vignetting, plane flow, JPEG tables)."""
from __future__ import annotations

import dataclasses
import io
import math

import numpy as np
import pytest
from PIL import Image

from roadtwin_core.errors import RoadtwinError
from roadtwin_core.params import check_params
from roadtwin_core.render.cameras import Camera, Intrinsics, look_from
from roadtwin_core.render.randomize import (ImageEffects, Ranges, apply_sensor, draw, forward_flow, motion_blur,
                                            sensor_noise, vignetting)


def _scene(seed=0, h=96, w=128):
    rng = np.random.default_rng(seed)
    return (rng.random((h, w, 3)) * 0.6).astype(np.float32)


def test_same_seed_and_index_give_identical_parameters_and_bytes():
    cam = Camera(Intrinsics.from_fov(128, 96, 60.0), look_from((0, 0, 2.4), 0.0, math.radians(-10)))
    depth = np.full((96, 128), 12.0)
    rgb = _scene()
    a, b = draw(7, 3), draw(7, 3)
    assert a == b
    img_a, jpg_a = apply_sensor(rgb, a.effects, cam, depth)
    img_b, jpg_b = apply_sensor(rgb, b.effects, cam, depth)
    assert jpg_a == jpg_b and np.array_equal(img_a, img_b)
    # frame 3 does not depend on which frames were drawn before it, or in what order
    forward = [draw(7, i) for i in range(6)]
    backward = [draw(7, i) for i in reversed(range(6))][::-1]
    assert forward == backward
    assert draw(7, 4) != a and draw(8, 3) != a
    assert apply_sensor(rgb, draw(7, 4).effects, cam, depth)[1] != jpg_a


def test_draws_stay_in_their_ranges_and_are_valid_render_params():
    ranges = Ranges()
    frames = [draw(1, i) for i in range(300)]
    el = np.array([f.render.sun_elevation_deg for f in frames])
    az = np.array([f.render.sun_azimuth_deg for f in frames])
    q = np.array([f.effects.jpeg_quality for f in frames])
    assert el.min() >= 15.0 and el.max() <= 75.0 and el.max() - el.min() > 50
    assert az.min() >= -180 and az.max() <= 180 and az.max() - az.min() > 300
    assert q.min() >= 60 and q.max() <= 95 and q.max() - q.min() >= 30
    wet = np.array([f.render.weather == "wet" for f in frames])
    assert 0.05 < wet.mean() < 0.2
    assert all(0.4 <= f.render.wetness <= 1.0 for f in frames if f.render.weather == "wet")
    assert all(f.render.wetness == 0.0 and f.render.weather == "clear" for f in frames if f.render.weather != "wet")
    assert all(f.look.wet_patch_coverage == 0.0 for f in frames if f.render.weather == "wet")
    for f in frames[:20]:
        check_params(f.render, "render")              # inside RenderParams' declared bounds
    assert {f.look.verge_surface for f in frames} == set(ranges.verge_surfaces)
    with pytest.raises(RoadtwinError, match="JPEG quality"):
        draw(1, 0, ranges=Ranges(jpeg_quality=(50, 120)))
    # pothole interiors: brightness spans its log-uniform range, warm (red >= green >= blue), some wet
    alb = np.array([f.look.pothole_albedo for f in frames])
    assert alb[:, 1].min() >= 0.6 and alb[:, 1].max() <= 2.4 and alb[:, 1].max() / alb[:, 1].min() > 3
    assert (alb[:, 0] >= alb[:, 1]).all() and (alb[:, 2] <= alb[:, 1]).all() and (alb[:, 2] >= 0.7 * alb[:, 1]).all()
    wet_holes = np.mean([f.look.pothole_surface == "pothole_wet" for f in frames])
    assert 0.07 < wet_holes < 0.25


@pytest.mark.parametrize("gain,read", [(1 / 500, 0.004), (1 / 2000, 0.001)])
def test_sensor_noise_variance_is_gain_times_signal_plus_read_squared(gain, read):
    rng = np.random.default_rng(0)
    for signal in (0.02, 0.1, 0.4):
        x = np.full((300, 300), signal, dtype=np.float32)
        y = sensor_noise(x, gain, read, rng).astype(np.float64)
        expected = gain * signal + read ** 2
        assert y.mean() == pytest.approx(signal, abs=4 * math.sqrt(expected / y.size))
        assert y.var() == pytest.approx(expected, rel=0.03)       # sampling error ~0.5 %


def test_vignetting_is_one_at_the_centre_cos4_at_the_corner_and_falls_monotonically():
    k = Intrinsics.from_fov(201, 121, 80.0)
    v = vignetting(k, 1.0)
    assert v[60, 100] == pytest.approx(1.0)
    corner = math.atan(math.hypot(100 / k.fx, 60 / k.fy))
    assert v[0, 0] == pytest.approx(math.cos(corner) ** 4, rel=1e-9)
    # along rays from the centre to every border pixel, relative illumination never rises
    border = [(0, c) for c in range(201)] + [(120, c) for c in range(201)] + [(r, 0) for r in range(121)] + \
             [(r, 200) for r in range(121)]
    for r, c in border[::7]:
        t = np.linspace(0, 1, 60)
        rows = np.rint(60 + t * (r - 60)).astype(int)
        cols = np.rint(100 + t * (c - 100)).astype(int)
        assert (np.diff(v[rows, cols]) <= 1e-12).all()
    weak = vignetting(k, 0.3)
    assert (weak >= v - 1e-12).all() and weak[0, 0] > v[0, 0]


def test_forward_flow_on_a_level_plane_matches_the_closed_form():
    """Camera h m above a plane, looking level along +x: a ground pixel at row v sees depth
    Z = fy h / (v - cy); after moving d forward it sits at row cy + fy h / (Z - d)."""
    h, d = 2.0, 0.5
    cam = Camera(Intrinsics.from_fov(160, 120, 60.0), look_from((0.0, 0.0, h), 0.0, 0.0))
    k = cam.intrinsics
    rows = np.arange(k.height, dtype=float)
    z = np.where(rows > k.cy + 2, k.fy * h / np.maximum(rows - k.cy, 1e-9), 0.0)
    depth = np.repeat(z[:, None], k.width, axis=1)
    flow = forward_flow(cam, depth, d)
    ground = rows > k.cy + 2
    expected_dv = k.cy + k.fy * h / (z[ground] - d) - rows[ground]
    assert np.allclose(flow[ground, k.width // 2, 1], expected_dv, rtol=1e-4)
    assert np.allclose(flow[ground, 0, 0], (0 - k.cx) * (z[ground] / (z[ground] - d) - 1), rtol=1e-4)
    assert (flow[~ground] == 0).all()


def test_motion_blur_spreads_a_point_along_its_flow_and_keeps_energy():
    img = np.zeros((64, 64, 3), np.float32)
    img[32, 32] = 1.0
    flow = np.zeros((64, 64, 2), np.float32)
    flow[..., 1] = 9.0                                  # 9 px straight down during the exposure
    out = motion_blur(img, flow)
    col = out[:, 32, 0]
    assert out.sum() == pytest.approx(3.0, rel=1e-4)
    lit = np.nonzero(col > 1e-4)[0]
    assert 8 <= lit.max() - lit.min() <= 10 and abs(lit.mean() - 32) <= 0.5
    assert np.abs(out[:, :31]).max() == 0 and np.abs(out[:, 34:]).max() == 0   # nothing sideways
    assert np.array_equal(motion_blur(img, np.zeros_like(flow)), img)


def _ijg_luma_table(quality: int) -> np.ndarray:
    base = np.array([16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                     14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
                     49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99])
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality
    return np.clip((base * scale + 50) // 100, 1, 255)


def test_jpeg_is_written_at_the_drawn_quality():
    rgb = _scene(3)
    for i in range(4):
        fx = draw(2, i).effects
        _, data = apply_sensor(rgb, fx)
        im = Image.open(io.BytesIO(data))
        assert im.format == "JPEG"
        assert np.array_equal(np.array(im.quantization[0]), _ijg_luma_table(fx.jpeg_quality))


def test_exposure_and_white_balance_scale_the_channels():
    flat = np.full((32, 32, 3), 0.1, np.float32)
    plain = apply_sensor(flat, ImageEffects(jpeg_quality=100))[0].astype(float)
    warm = apply_sensor(flat, ImageEffects(wb_gains=(1.3, 1.0, 0.7), jpeg_quality=100))[0].astype(float)
    bright = apply_sensor(flat, ImageEffects(exposure=2.0, jpeg_quality=100))[0].astype(float)
    assert warm[..., 0].mean() > plain[..., 0].mean() + 10 and warm[..., 2].mean() < plain[..., 2].mean() - 10
    assert abs(warm[..., 1].mean() - plain[..., 1].mean()) < 2
    assert (bright.mean(axis=(0, 1)) > plain.mean(axis=(0, 1)) + 15).all()
    with pytest.raises(RoadtwinError, match="linear RGB"):
        apply_sensor(flat[..., 0], ImageEffects())
    assert dataclasses.asdict(ImageEffects())["jpeg_quality"] == 95
