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
