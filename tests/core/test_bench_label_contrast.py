"""bench/label_contrast.py's Weber contrast of labelled instances against a closed form: grey road
and flat-coloured defects of known luma (issue 22: photo crack strokes rendered invisible)."""
from __future__ import annotations


import cv2
import numpy as np
import pytest
from bench_script import load_bench_script



def _bench():
    return load_bench_script("label_contrast")


def _luma(value) -> float:
    return float(np.dot(np.asarray(value, float) / 255.0, [0.2126, 0.7152, 0.0722]))


def test_a_dark_bar_on_grey_road_has_its_weber_contrast():
    """Road (120, 110, 100), a 2 px bar (60, 50, 40): C = (L_road - L_bar) / L_road; a pothole
    touching the bar's ring (brighter, another defect class) is kept out of the ring."""
    road, bar, hole = (120, 110, 100), (60, 50, 40), (250, 250, 250)
    rgb = np.empty((60, 200, 3), np.uint8)
    rgb[:] = road
    label = np.ones((60, 200), np.uint8)
    rgb[20:22, 30:170] = bar
    label[20:22, 30:170] = 2
    rgb[22:40, 80:100] = hole                # right below the bar: inside its 2 px ring if it were road
    label[22:40, 80:100] = 3
    c = _bench().instance_contrasts(rgb, label, 2, (2, 3), ring_px=2)
    expected = (_luma(road) - _luma(bar)) / _luma(road)
    assert c == [pytest.approx((expected, expected), abs=1e-12)]                  # uniform: its core is itself
    (c_hole,) = _bench().instance_contrasts(rgb, label, 3, (2, 3), ring_px=2)
    assert c_hole[0] == pytest.approx((_luma(road) - _luma(hole)) / _luma(road), abs=1e-12)   # brighter: C < 0


def test_a_label_wider_than_its_dark_core_averages_the_core_and_its_rim():
    """A 3 px label over a 1 px black core and 2 px of road: C = (1/3) x 1 (the label is a blend:
    a third of it has contrast 1, the rest 0) and C_core = 1 (its darkest third: the core);
    invisible labels give 0; tiny instances are dropped."""
    rgb = np.full((40, 120, 3), 100, np.uint8)
    label = np.ones((40, 120), np.uint8)
    label[10:13, 10:110] = 2
    rgb[11, 10:110] = 0
    label[25:28, 10:110] = 2                  # labelled, nothing drawn
    label[35, 5:9] = 2                        # 4 px: below MIN_PIXELS
    c = sorted(_bench().instance_contrasts(rgb, label, 2, (2, 3), ring_px=2))
    assert c == [pytest.approx((0.0, 0.0), abs=1e-12), pytest.approx((1 / 3, 1.0), abs=1e-12)]


def test_folder_of_a_split_reads_images_and_labels(tmp_path):
    """A dataset split: images/ and labels/ paired by stem (PNG images here: flat colours, no JPEG loss)."""
    (tmp_path / "images").mkdir()
    (tmp_path / "labels").mkdir()
    rgb = np.full((32, 64, 3), 200, np.uint8)
    rgb[10:14, 5:60] = 100
    label = np.zeros((32, 64), np.uint8)
    label[10:14, 5:60] = 2
    cv2.imwrite(str(tmp_path / "images" / "a.png"), rgb)
    cv2.imwrite(str(tmp_path / "labels" / "a.png"), label)
    out = _bench().folder_contrasts(tmp_path)
    assert out["crack"] == [pytest.approx((0.5, 0.5), abs=1e-12)] and out["pothole"] == []
