"""The loop back (issue 20, item 5) on the sample town, end to end: compose, drive 2 s with a
stereo pair and a LiDAR, reconstruct the surface from the bag's LiDAR scans and poses and the
potholes from SGBM disparity on the bag's stereo pairs, score against the twin's own truth
(bench/loop.py's functions). Slow: about a minute on two cores (compose 10 s, the drive's
rendering most of the rest).

The surface target is the issue's (height RMSE <= 5 mm against the collision mesh); the stereo
figures are only checked to be computed from the bag (what they are is bench/loop.py's report).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

for _package in ("rosbags", "open3d", "warp"):
    pytest.importorskip(_package)

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def loop():
    sys.path[:0] = [str(REPO / "bench")]
    import loop as loop_module

    return loop_module


@pytest.fixture(scope="module")
def drive(loop, tmp_path_factory):
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.apps.drive import DriveOptions, run_drive
    from roadtwin_core.plugins import PluginManager

    tmp = tmp_path_factory.mktemp("loop")
    compose(REPO / "stages" / "town.usda", tmp / "town", preview=False, executor="serial", pm=PluginManager())
    rig = tmp / "rig.toml"
    rig.write_text(loop.RIG.format(w=320, h=180))
    opt = DriveOptions(route="auto", length_m=None, duration_s=2.0, speed_kmh=20.0, rig=rig, rrd=False)
    run_drive(tmp / "town" / "town.usda", tmp / "drive", opt, pm=PluginManager())
    return tmp / "town" / "town.usda", tmp / "drive"


def test_surface_from_the_drive_matches_the_twin(loop, drive):
    stage, out = drive
    truth = loop.load_truth(stage)
    summary = json.loads((out / "summary.json").read_text())
    s = loop.surface_figures(loop.Bag(out), summary["classes"], truth)
    print(s)
    assert s["scans"] == 20 and s["vertices"] > 500
    assert s["rmse_mm"] <= 5.0


def test_stereo_figures_come_from_the_bag(loop, drive):
    stage, out = drive
    truth = loop.load_truth(stage)
    summary = json.loads((out / "summary.json").read_text())
    st = loop.stereo_figures(loop.Bag(out), summary["instances"], truth, summary["classes"])
    print({k: v for k, v in st.items() if k != "rows"})
    assert st["frames"] == 20
    assert all(0.0 <= r["iou"] <= 1.0 and r["dist_m"] >= 0 for r in st["rows"])
    assert np.isfinite(st["per_frame_mean"])
