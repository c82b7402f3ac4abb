"""Stereo defect reconstructor (issue 4, item 2): real frames vs labels, Fan et al.'s disparity
transformation on a synthetic tilted and rolled road, and 3D reconstruction vs a known bowl.

The plugin is registered by hand (``PluginManager(load_entry_points=False)``) so these tests do not
depend on the entry point being installed.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.plugins import PluginManager

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parents[1] / "data" / "stereo_pothole"

import roadtwin_stereo as rs
from roadtwin_stereo.synthetic import BowlScene, hausdorff_to_bowl, mesh_samples

# The detector's label-chosen numbers are chosen by leave-one-out over the 13 frames
# (bench/stereo_cv.py, docs/stereo_detector.md): with the local road model (issue 20) the folds
# chose tile_frac 0.0625 (shipped) and k_seed 15 (shipped: 10, which the synthetic SGBM bowl needs).
# F1 with the shipped defaults measured 2026-11-26 on frames 01-05: 0.930 0.929 0.931 0.920 0.816
# (frame 5's label leaves out the left third of the pothole the disparity shows). Modest floors.
F1_FLOOR_FRAME = 0.80
F1_FLOOR_MEAN = 0.85

@pytest.fixture(scope="module")
def stereo():
    pm = PluginManager(load_entry_points=False)
    pm.register(rs, name="stereo")
    return pm.get("reconstructors", "stereo_defects")

def test_registered(stereo):
    assert stereo.name == "stereo_defects" and stereo.produces == "defects"
    assert stereo.description

def test_real_frames_f1(stereo):
    assert (DATA / "LICENSE").exists()
    scores = []
    for i in range(1, 6):
        r = stereo.run({"disparity": DATA / "disp_tg" / f"0{i}.png", "transformed": True})
        label = rs.load_label(DATA / "label" / f"0{i}.png")
        assert r.labels.shape == label.shape
        scores.append(rs.f1_score(r.labels > 0, label))
    print("F1 per frame", np.round(scores, 3), "mean", round(float(np.mean(scores)), 3))
    assert min(scores) >= F1_FLOOR_FRAME
    assert np.mean(scores) >= F1_FLOOR_MEAN

SHARED = ROOT.parent / "shared" / "data" / "stereo_pothole"

@pytest.mark.slow
@pytest.mark.skipif(not (SHARED / "disp_tg" / "13.png").exists(), reason="the 13 frames live in ../shared/data")
def test_all_13_real_frames_f1(stereo):
    """All 13 frames with the shipped defaults (chosen by leave-one-out in bench/stereo_cv.py:
    every fold chose them, so these are held-out figures): mean F1 >= 0.9 (issue 20)."""
    scores = []
    for i in range(1, 14):
        r = stereo.run({"disparity": SHARED / "disp_tg" / f"{i:02d}.png", "transformed": True})
        scores.append(rs.f1_score(r.labels > 0, rs.load_label(SHARED / "label" / f"{i:02d}.png")))
    print("F1 per frame", np.round(scores, 3), "mean", round(float(np.mean(scores)), 3))
    assert np.mean(scores) >= 0.9
    assert min(scores) >= F1_FLOOR_FRAME

def test_disparity_transformation_roll_and_flatness():
    sc = BowlScene(tilt_deg=45, roll_deg=5.0, distance=3.0, offset=(0.3, 0.2), width=480, height=360, f=520.0)
    noise = 0.05
    d = sc.disparity(noise, seed=1)
    assert np.std(d) > 2.0  # the raw road disparity is far from flat
    dt, model = rs.transform_disparity(d)
    assert abs(np.degrees(model.theta - sc.roll_angle_image)) < 0.05
    v, u = np.mgrid[0:sc.height, 0:sc.width].astype(float)
    z = sc.depth_map()
    ray = np.stack([(u - sc.K[0, 2]) / sc.f, (v - sc.K[1, 2]) / sc.f, np.ones_like(u)], -1) * z[..., None]
    loc = sc.to_local(ray.reshape(-1, 3)).reshape(ray.shape)
    outside = loc[..., 0] ** 2 + loc[..., 1] ** 2 > sc.radius ** 2
    assert np.std(dt[outside]) < 1.5 * noise  # flat road after the transformation
    assert abs(np.median(dt[outside]) - model.delta) < 0.05
    assert np.min(dt[~outside]) - model.delta < -0.3  # the pothole lies below (farther)
    lab = rs.segment_defects(dt)
    assert lab.max() == 1

@pytest.fixture(scope="module")
def bowl_result(stereo):
    sc = BowlScene(tilt_deg=30, roll_deg=2.0, distance=1.5, depth=0.05, radius=0.25, offset=(0.05, -0.03))
    return sc, stereo.run({"disparity": sc.disparity(0.1, seed=2), "K": sc.K, "baseline": sc.baseline,
                           "source": "synthetic/left_0001.png"})

def test_bowl_volume_and_hausdorff(bowl_result):
    sc, r = bowl_result
    assert len(r.models) == 1
    m, inst = r.models[0], r.instances[0]
    vol_err = abs(m.volume_m3 - sc.volume) / sc.volume
    hd, mean_d = hausdorff_to_bowl(sc, inst.to_camera(mesh_samples(m.vertices, m.faces)))
    print(f"volume error {100 * vol_err:.2f} %, Hausdorff {1000 * hd:.1f} mm (mean {1000 * mean_d:.2f} mm)")
    assert vol_err <= 0.10
    assert hd <= 0.01
    assert abs(m.depth_m - sc.depth) < 0.005
    assert np.all(m.vertices[m.boundary, 2] == 0) and m.pseudo_height[m.boundary].all()
    assert m.source == "synthetic/left_0001.png"

def test_sgbm_pair_end_to_end(stereo):
    """Rendered textured pair -> OpenCV SGBM -> transformation -> mesh. Measured: volume error
    -2.0 %, Hausdorff 12 mm (SGBM's spatially correlated errors; the 1 cm target is met on exact
    disparity + noise above, not through SGBM). Floors: 10 % and 15 mm."""
    sc = BowlScene(tilt_deg=30, roll_deg=2.0, distance=1.5, depth=0.05, radius=0.25, offset=(0.05, -0.03))
    left, right = sc.stereo_pair(seed=3)
    r = stereo.run({"left": left, "right": right, "K": sc.K, "baseline": sc.baseline})
    assert len(r.models) == 1
    m, inst = r.models[0], r.instances[0]
    hd, _ = hausdorff_to_bowl(sc, inst.to_camera(mesh_samples(m.vertices, m.faces)))
    assert abs(m.volume_m3 - sc.volume) / sc.volume <= 0.10
    assert hd <= 0.015

def test_write_assets_and_mask(stereo, bowl_result, tmp_path):
    import cv2

    from roadtwin_core.usd.library import read_defect_asset

    _, r = bowl_result
    paths = stereo.write(r, tmp_path / "out")
    assert len(paths) == 1 and paths[0].exists()
    mask = cv2.imread(str(tmp_path / "out" / "mask.png"), cv2.IMREAD_UNCHANGED)
    assert mask.shape == r.labels.shape and (mask > 0).sum() == (r.labels > 0).sum()
    back = read_defect_asset(paths[0])
    assert back.volume_m3 == pytest.approx(r.models[0].volume_m3, rel=1e-6)
    assert back.source == "synthetic/left_0001.png"

def test_bad_input(stereo, tmp_path):
    sc = BowlScene(width=160, height=120, f=175.0)
    d = sc.disparity()
    with pytest.raises(RoadtwinError, match="calibration"):
        stereo.run({"disparity": d})
    with pytest.raises(RoadtwinError, match="no road"):
        stereo.run({"disparity": np.full_like(d, np.nan), "K": sc.K, "baseline": 0.12})
    with pytest.raises(RoadtwinError, match="differ in size"):
        stereo.run({"left": np.zeros((120, 160), np.uint8), "right": np.zeros((100, 160), np.uint8),
                    "K": sc.K, "baseline": 0.12})
    with pytest.raises(RoadtwinError, match="baseline"):
        stereo.run({"disparity": d, "K": sc.K, "baseline": -1.0})
    with pytest.raises(RoadtwinError, match="no such"):
        stereo.run({"disparity": tmp_path / "missing.png", "transformed": True})
    assert not any(tmp_path.iterdir())

def test_cli_reconstruct_defects(monkeypatch, tmp_path):
    from typer.testing import CliRunner
    import typer

    from roadtwin_core import plugins as plugins_mod
    from roadtwin_core.cli.reconstruct import reconstruct_app

    pm = PluginManager(load_entry_points=False)
    pm.register(rs, name="stereo")
    monkeypatch.setattr(plugins_mod, "_manager", pm)
    app = typer.Typer()
    app.add_typer(reconstruct_app, name="reconstruct")
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["reconstruct", "defects", "--disparity", str(DATA / "disp_tg" / "03.png"),
                                   "--transformed", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert (out / "mask.png").exists() and (out / "instances.json").exists()

def test_bad_input_files_one_line_nothing_written(monkeypatch, tmp_path):
    """Bad stereo input through ``roadtwin reconstruct defects``: one RoadtwinError line naming the
    file; no new output folder, and an earlier one left exactly as it was."""
    import cv2
    import typer
    from typer.testing import CliRunner

    from roadtwin_core import plugins as plugins_mod
    from roadtwin_core.cli.reconstruct import reconstruct_app

    pm = PluginManager(load_entry_points=False)
    pm.register(rs, name="stereo")
    monkeypatch.setattr(plugins_mod, "_manager", pm)
    app = typer.Typer()
    app.add_typer(reconstruct_app, name="reconstruct")
    runner = CliRunner()

    earlier = tmp_path / "earlier"
    res = runner.invoke(app, ["reconstruct", "defects", "--disparity", str(DATA / "disp_tg" / "03.png"),
                              "--transformed", "-o", str(earlier)])
    assert res.exit_code == 0, res.output
    before = {p.name: p.read_bytes() for p in earlier.iterdir()}

    inp = tmp_path / "in"
    inp.mkdir()
    rng = np.random.default_rng(0)
    assert cv2.imwrite(str(inp / "left.png"), rng.integers(0, 255, (120, 160), dtype=np.uint8))
    assert cv2.imwrite(str(inp / "right.png"), rng.integers(0, 255, (120, 160), dtype=np.uint8))
    assert cv2.imwrite(str(inp / "right_short.png"), rng.integers(0, 255, (100, 160), dtype=np.uint8))
    assert cv2.imwrite(str(inp / "no_road.png"), np.zeros((120, 160), np.uint16))  # every pixel invalid
    sparse = np.zeros((120, 160), np.uint16)
    sparse[:3, :] = 40 * 256  # 2.5 % valid pixels
    assert cv2.imwrite(str(inp / "sparse.png"), sparse)
    sc = BowlScene(width=160, height=120, f=175.0)
    assert cv2.imwrite(str(inp / "disp.png"), np.round(sc.disparity() * 256).astype(np.uint16))
    calib = ["--K", f"{sc.f},{sc.f},{sc.K[0, 2]},{sc.K[1, 2]}", "--baseline", "0.12"]
    pair = ["--left", str(inp / "left.png"), "--right", str(inp / "right.png")]

    cases = [
        (["--left", str(inp / "left.png"), "--right", str(inp / "right_short.png"), *calib],
         ["right_short.png", "differ in size", "160x100", "160x120"]),
        (pair, ["left.png", "calibration", "K and baseline missing"]),
        ([*pair, *calib[:2]], ["left.png", "calibration", "baseline missing"]),
        ([*pair, *calib[2:]], ["left.png", "calibration", "K missing"]),
        (["--disparity", str(inp / "disp.png"), "--disparity-scale", "256"], ["disp.png", "calibration"]),
        (["--disparity", str(inp / "no_road.png"), *calib], ["no_road.png", "no valid disparity", "no road"]),
        (["--disparity", str(inp / "sparse.png"), "--disparity-scale", "256", *calib], ["sparse.png", "no road"]),
    ]
    for args, expect in cases:
        for out in (tmp_path / "new_out", earlier):
            res = runner.invoke(app, ["reconstruct", "defects", *args, "-o", str(out)])
            assert res.exit_code != 0, (args, res.output)
            msg = str(res.exception)
            assert isinstance(res.exception, RoadtwinError), (args, repr(res.exception))
            assert "\n" not in msg and all(e in msg for e in expect), (args, msg)
    assert not (tmp_path / "new_out").exists()
    assert {p.name: p.read_bytes() for p in earlier.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["earlier", "in"]  # no temporary folders left

def _true_pothole_mask(sc: BowlScene) -> np.ndarray:
    """Closed form: the pixels whose ray meets the road inside the bowl's rim (r < R)."""
    v, u = np.mgrid[0:sc.height, 0:sc.width].astype(float)
    z = sc.depth_map()
    ray = np.stack([(u - sc.K[0, 2]) / sc.f, (v - sc.K[1, 2]) / sc.f, np.ones_like(u)], -1) * z[..., None]
    loc = sc.to_local(ray.reshape(-1, 3)).reshape(ray.shape)
    return loc[..., 0] ** 2 + loc[..., 1] ** 2 < sc.radius ** 2

# What changes between roads and days: roll, pitch (tilt), noise, disparity range (baseline),
# pothole size from 0.5 % to ~40 % of the frame. The previous detector (fixed seed area, sigma over
# every pixel) found nothing in the large-pothole case.
SYNTHETIC_ROADS = {
    "medium": dict(tilt_deg=30, roll_deg=0.0, radius=0.25, depth=0.05, noise=0.05),
    "small_rolled_noisy": dict(tilt_deg=45, roll_deg=6.0, radius=0.08, depth=0.03, distance=2.0, noise=0.1),
    "large_share": dict(tilt_deg=35, roll_deg=-4.0, radius=0.45, depth=0.06, noise=0.05),
    "short_baseline": dict(tilt_deg=40, roll_deg=3.0, radius=0.2, depth=0.04, baseline=0.03, noise=0.02),
    "long_baseline_rolled": dict(tilt_deg=25, roll_deg=-8.0, radius=0.2, depth=0.04, baseline=0.5, noise=0.1),
}

@pytest.mark.parametrize("name", sorted(SYNTHETIC_ROADS))
def test_synthetic_potholes_found_at_true_size(name):
    kw = dict(SYNTHETIC_ROADS[name])
    noise = kw.pop("noise")
    sc = BowlScene(width=320, height=240, f=350.0, offset=(0.05, -0.03), **kw)
    truth = _true_pothole_mask(sc)
    dt, _ = rs.transform_disparity(sc.disparity(noise, seed=1))
    lab = rs.segment_defects(dt)
    pred = lab > 0
    f1 = rs.f1_score(pred, truth)
    print(name, "true px", int(truth.sum()), "found", int(pred.sum()), "F1", round(f1, 3))
    assert lab.max() == 1  # one pothole, no false regions
    assert f1 >= 0.85
    assert 0.8 <= pred.sum() / truth.sum() <= 1.25  # neither missed nor grown into the road

def test_segmentation_ignores_affine_rescaling():
    """Fan et al.'s maps are min-max normalised per frame: any positive gain and offset of the
    values must give the same pixels."""
    sc = BowlScene(width=320, height=240, f=350.0, tilt_deg=35, roll_deg=4.0, offset=(0.05, -0.03))
    dt, _ = rs.transform_disparity(sc.disparity(0.05, seed=4))
    a = rs.segment_defects(dt) > 0
    b = rs.segment_defects(dt * 731.0 + 12000.0) > 0
    assert a.sum() > 0 and rs.f1_score(a, b) > 0.995
