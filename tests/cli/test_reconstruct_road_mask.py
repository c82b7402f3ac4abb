"""``roadtwin reconstruct defects --road-mask`` through the real command line, on a synthetic road
with two bowl potholes whose pixels are known in closed form (``RoadScene.pothole_masks``): a
mask that takes one pothole's region off the road removes that detection and keeps the other; a
missing or wrong-size mask is one line on stderr, exit 2, and nothing is written."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cli_run import run_cli
from roadtwin_stereo.synthetic import RoadScene

POTHOLES = ((-0.5, 0.2, 0.22, 0.05), (0.55, 1.2, 0.25, 0.05))   # (x, y, R, D) in the road plane, m


@pytest.fixture(scope="module")
def road(tmp_path_factory):
    """The disparity (.npy), its calibration options and the true pixels of each pothole."""
    sc = RoadScene(width=320, height=240, f=267.0, baseline=0.12, tilt_deg=60, roll_deg=1.0, distance=2.4,
                   potholes=POTHOLES)
    folder = tmp_path_factory.mktemp("road")
    np.save(folder / "disp.npy", sc.disparity(0.05, seed=1))
    calib = ["--K", f"{sc.f},{sc.f},{sc.K[0, 2]},{sc.K[1, 2]}", "--baseline", str(sc.baseline)]
    return folder, ["--disparity", folder / "disp.npy", *calib], sc.pothole_masks()


def detected(out: Path) -> np.ndarray:
    return cv2.imread(str(out / "mask.png"), cv2.IMREAD_UNCHANGED) > 0


def test_mask_off_a_pothole_removes_its_detection(road, tmp_path):
    folder, args, (first, second) = road
    r = run_cli("reconstruct", "defects", *args, "-o", tmp_path / "all")
    assert r.returncode == 0, r.stderr
    found = detected(tmp_path / "all")
    assert found[first].mean() >= 0.5 and found[second].mean() >= 0.5     # both found without a mask

    off_first = cv2.dilate(first.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0   # its region and rim
    assert cv2.imwrite(str(folder / "road.png"), np.where(off_first, 0, 255).astype(np.uint8))
    r = run_cli("reconstruct", "defects", *args, "--road-mask", folder / "road.png", "-o", tmp_path / "masked")
    assert r.returncode == 0, r.stderr
    assert "1 defect instance(s)" in r.stdout, r.stdout
    found = detected(tmp_path / "masked")
    assert not found[off_first].any()                # nothing detected off the road
    assert found[second].mean() >= 0.5               # the other pothole still is


@pytest.mark.parametrize("mask, needles", [("missing.png", ["missing.png", "no such road mask"]),
                                           ("small.png", ["small.png", "160x120", "320x240"])])
def test_bad_mask_one_line_exit_2_nothing_written(road, tmp_path, mask, needles):
    folder, args, _ = road
    assert cv2.imwrite(str(folder / "small.png"), np.full((120, 160), 255, np.uint8))
    out = tmp_path / "out"
    r = run_cli("reconstruct", "defects", *args, "--road-mask", folder / mask, "-o", out)
    err = r.stderr.strip()
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "\n" not in err and "Traceback" not in err and all(n in err for n in needles), err
    assert not out.exists()
