"""Camera targets (bench/camera_stats.py -> roadtwin_core/render/camera_targets/*.json): the
randomizer's defaults stay as they were unless a targets file is selected (by the class map),
a selected file's ranges are what draw() samples from, and the sensor model's new steps
(optics blur, auto-exposure, saturation) do what they say."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from roadtwin_core import RoadtwinError
from roadtwin_core.render.classmap import load_class_map
from roadtwin_core.render.randomize import ImageEffects, Ranges, apply_sensor, auto_exposure, draw
from bench_script import load_bench_script

ROOT = Path(__file__).resolve().parents[2]


def _camera_stats():
    return load_bench_script("camera_stats")


def test_defaults_unchanged_without_targets():
    fr = draw(3, 5)
    e = fr.effects
    assert (e.saturation, e.blur_px, e.target_luminance) == (1.0, 0.0, None)
    assert not {"saturation", "blur_px", "target_luminance"} & set(e.as_dict())   # frame records as before
    assert draw(3, 5, ranges=Ranges()) == fr


def test_builtin_targets_load_and_bound_the_draws():
    cmap = load_class_map("road_defects_br")
    assert cmap.camera_targets == "road_defects_br"
    r = Ranges.from_targets(cmap.camera_targets)
    doc = json.loads((ROOT / "roadtwin_core/render/camera_targets/road_defects_br.json").read_text())
    assert "val" not in doc["source"].replace("never val", "")
    assert r.jpeg_quality == tuple(doc["ranges"]["jpeg_quality"]) and r.vignetting == tuple(doc["ranges"]["vignetting"])
    # fields the file does not set keep their defaults (sun, weather, looks)
    assert r.sun_elevation_deg == Ranges().sun_elevation_deg and r.verge_surfaces == Ranges().verge_surfaces
    for i in range(20):
        e = draw(0, i, ranges=r).effects
        assert r.vignetting[0] <= e.vignetting <= r.vignetting[1]
        assert r.jpeg_quality[0] <= e.jpeg_quality <= r.jpeg_quality[1]
        lo, hi = r.frame_luminance
        assert lo * (1 - 1e-9) <= e.target_luminance <= hi * (1 + 1e-9)
        t = (e.wb_gains[0] - e.wb_gains[2]) / 2
        assert r.wb_temperature[0] - 1e-9 <= t <= r.wb_temperature[1] + 1e-9
    # the draws the targets do not touch are the same as without them (own random stream)
    assert draw(0, 4, ranges=r).render == draw(0, 4).render


def test_bad_targets_are_one_line(tmp_path):
    with pytest.raises(RoadtwinError, match="no camera targets"):
        Ranges.from_targets("nowhere")
    bad = tmp_path / "t.json"
    bad.write_text(json.dumps({"ranges": {"vignetting": [1.0, 0.5]}}))
    with pytest.raises(RoadtwinError, match="lo <= hi"):
        Ranges.from_targets(bad)
    bad.write_text("{}")
    with pytest.raises(RoadtwinError, match="ranges"):
        Ranges.from_targets(bad)


def test_auto_exposure_hits_the_displayed_luminance():
    rng = np.random.default_rng(0)
    img = rng.uniform(0.02, 0.6, (64, 96, 3)).astype(np.float32)
    out, _ = apply_sensor(img, ImageEffects(target_luminance=0.2, jpeg_quality=100))
    lin = np.where(out / 255 <= 0.04045, out / 255 / 12.92, ((out / 255 + 0.055) / 1.055) ** 2.4)
    assert float((lin @ np.array([0.2126, 0.7152, 0.0722])).mean()) == pytest.approx(0.2, abs=0.01)
    assert auto_exposure(img, 0.2) > 0


def test_saturation_and_blur():
    rng = np.random.default_rng(1)
    img = rng.uniform(0.05, 0.5, (64, 64, 3)).astype(np.float32)
    flat, _ = apply_sensor(img, ImageEffects(jpeg_quality=100))
    grey, _ = apply_sensor(img, ImageEffects(jpeg_quality=100, saturation=0.0))
    assert np.abs(grey.astype(int) - grey.mean(axis=2, keepdims=True)).max() <= 3 < np.abs(
        flat.astype(int) - flat.mean(axis=2, keepdims=True)).max()
    soft, _ = apply_sensor(img, ImageEffects(jpeg_quality=100, blur_px=1.5))
    assert soft.astype(float).std() < 0.7 * flat.astype(float).std()


def test_camera_stats_refuses_val_and_estimates_jpeg_quality(tmp_path):
    camera_stats = _camera_stats()
    with pytest.raises(SystemExit, match="evaluation split"):
        camera_stats.refuse_eval(tmp_path / "val")
    img = (np.random.default_rng(2).uniform(0, 255, (64, 64, 3))).astype(np.uint8)
    for q in (60, 75, 85, 95):
        Image.fromarray(img).save(tmp_path / f"{q}.jpg", quality=q)
        assert camera_stats.jpeg_quality(tmp_path / f"{q}.jpg") == q
    # a known vignetting on a flat grey road is recovered
    h, w = 80, 128
    f = (w / 2) / np.tan(np.radians(camera_stats.HFOV_DEG) / 2)
    u, v = np.meshgrid(np.arange(w) - (w - 1) / 2, np.arange(h) - (h - 1) / 2)
    lin = 0.2 * (1 / (1 + (u * u + v * v) / f ** 2)) ** (2 * 0.5)
    num, den = camera_stats.vignetting_fit(lin, np.ones((h, w), bool))
    assert num / den == pytest.approx(0.5, abs=1e-6)
