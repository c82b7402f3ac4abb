"""bench/label_stats.py measures stroke width as 2A/P, and bench/synthetic_set.py's --no-camera
class map keeps every class while dropping only the measured camera targets (issue 22's ablation)."""
from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from roadtwin_core.render.classmap import load_class_map
from bench_script import load_bench_script



def _load(name: str):
    return load_bench_script(name)


@pytest.mark.parametrize("width", [2, 3, 6])
def test_a_long_stroke_measures_its_width(width):
    """A 300 px long, w px wide bar: every pixel of its two long edges and of its short edges'
    interior is boundary, so 2A/P = 2*300w / (600 + 2(w - 2)) ~ w (closed form)."""
    mask = np.zeros((64, 400), bool)
    mask[20:20 + width, 50:350] = True
    width_px = _load("label_stats").stroke_width(mask)
    assert width_px == pytest.approx(2 * 300 * width / (600 + 2 * (width - 2)), rel=1e-9)
    assert abs(width_px - width) < 0.02 * width


def test_a_one_pixel_stroke_measures_two():
    """All of a 1 px line is boundary: 2A/P = 2, the measure's floor (why real cracks read 2.55)."""
    mask = np.zeros((64, 400), bool)
    mask[20, 50:350] = True
    assert _load("label_stats").stroke_width(mask) == 2.0


def test_a_filled_disc_measures_about_its_radius():
    """A digital disc of radius r has ~4 sqrt(2) r boundary pixels (an 8-connected ring), so
    2A/P ~ 2 pi r^2 / (4 sqrt(2) r) = 1.11 r: far wider than a crack stroke."""
    mask = np.zeros((200, 200), np.uint8)
    cv2.circle(mask, (100, 100), 40, 1, -1)
    assert _load("label_stats").stroke_width(mask.astype(bool)) == pytest.approx(np.pi * 40 / (2 * np.sqrt(2)), rel=0.03)


def test_folder_stats_reads_shares_of_a_label_folder(tmp_path):
    lab = np.zeros((100, 100), np.uint8)
    lab[:50] = 1                      # ego lane: half the frame
    lab[60:62, 10:90] = 2             # crack: 160 px
    lab[80:90, 80:90] = 3             # pothole: 100 px
    cv2.imwrite(str(tmp_path / "a.png"), lab)
    s = _load("label_stats").folder_stats(tmp_path, every=1)
    assert s["share_pct"][1:] == [50.0, 1.6, 1.0]
    assert s["crack_frames"] == 1 and s["pothole_frames"] == 1


def test_no_camera_class_map_drops_only_the_camera_targets(tmp_path):
    synthetic_set = _load("synthetic_set")
    with_camera = load_class_map(synthetic_set.class_map(SimpleNamespace(no_camera=False, label_range=None), tmp_path)
                                 .removeprefix("builtin:"))
    without = load_class_map(synthetic_set.class_map(SimpleNamespace(no_camera=True, label_range=None), tmp_path))
    assert with_camera.camera_targets == "road_defects_br" and without.camera_targets is None
    assert without.classes == with_camera.classes
    assert (without.plain, without.ego, without.dilate_px) == (with_camera.plain, with_camera.ego, with_camera.dilate_px)


def test_elongation_of_a_bar_and_a_disc_follows_their_second_moments():
    """A w x h bar of pixels: the variances of its columns and rows are (w^2 - 1)/12 and (h^2 - 1)/12
    (discrete uniform), so its elongation is sqrt((w^2 - 1)/(h^2 - 1)); a disc's is 1."""
    stats = _load("label_stats")
    bar = np.zeros((100, 200), bool)
    bar[40:46, 20:80] = True
    assert stats.elongation(bar) == pytest.approx(np.sqrt((60 ** 2 - 1) / (6 ** 2 - 1)), rel=1e-6)
    disc = np.zeros((200, 200), np.uint8)
    cv2.circle(disc, (100, 100), 40, 1, -1)
    assert stats.elongation(disc.astype(bool)) == pytest.approx(1.0, abs=0.01)


def test_road_stats_count_each_roads_pothole_pixels_and_its_largest_component(tmp_path):
    """Two roads of road_defects_br-named frames: RS_290 with a 20 x 100 px strip (2,000 px) and a
    5 x 5 speck in one frame, DF_070 with a 10 x 10 hole in one of two frames. Its pothole pixels
    per frame, its share of the folder's (2,025 / 2,125), the component its median pixel belongs to
    (the strip, not the speck) and the frame with the most pothole pixels."""
    stats = _load("label_stats")
    a = np.zeros((320, 512), np.uint8)
    a[100:200, 300:320] = 3                       # the strip: 100 rows x 20 columns
    a[10:15, 10:15] = 3                           # a 25 px speck
    b = np.zeros((320, 512), np.uint8)
    b[250:260, 250:260] = 3
    for name, lab in (("1_RS_290_a", a), ("2_DF_070_a", b), ("3_DF_070_b", np.zeros_like(b))):
        cv2.imwrite(str(tmp_path / f"{name}.png"), lab)
    roads = stats.road_stats(tmp_path)
    assert list(roads) == ["RS_290", "DF_070"]                       # most pothole pixels first
    rs, df = roads["RS_290"], roads["DF_070"]
    assert (rs["frames"], rs["pothole_frames"], rs["components"]) == (1, 1, 2)
    assert rs["pothole_px_per_frame"] == 2025 and df["pothole_px_per_frame"] == 50
    assert rs["pothole_share"] == pytest.approx(2025 / 2125) and df["pothole_share"] == pytest.approx(100 / 2125)
    assert rs["median_area_px"] == 2000
    assert rs["median_elongation"] == pytest.approx(np.sqrt((100 ** 2 - 1) / (20 ** 2 - 1)), rel=1e-6)
    assert rs["top_frame"] == "1_RS_290_a" and df["top_frame"] == "2_DF_070_a"
