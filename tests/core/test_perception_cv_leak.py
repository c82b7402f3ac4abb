"""The guard against issue 21's CV leak: a synthetic set whose textures were cut from real train
frames (photo defect library, photo road surfaces) must not be scored by the mixed arm's CV on
those frames. bench/synthetic_set.py records the frames (sources.json); the CV refuses a fold
whose held-out frames are listed, in one line, before any model is trained."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf

from test_perception_bench import SMALL, TINY, _bench, make_standin_synthetic
from bench_script import load_bench_script

TRAIN_STEMS = sorted(p.stem for p in (TINY / "train/images").iterdir())
LEAKED = "1050564_DF_080_080BDF0050_1_00368"           # tiny train, road DF_080
CV_ARGS = [*SMALL, "--arms", "c", "--fractions", "1", "--cv-ratios", "0.5", "--cv-schedules", "constant",
           "--cv-folds", "2", "--cv-steps", "2", "--cv-only"]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def _synthetic_set():
    return load_bench_script("synthetic_set")


def test_cv_refuses_a_set_holding_a_held_out_train_frame(tmp_path, capsys):
    """Folds by road on the tiny train (RS_290 x2 | DF_080 + DF_251, worked out by hand from
    cv_folds' largest-road-first rule): the leaked DF_080 frame is 1 of the 2 held out in fold 2."""
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    (synth / "sources.json").write_text(json.dumps({"frames": [LEAKED, "somewhere_else_0001"]}))
    out = tmp_path / "o"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *CV_ARGS, "--out", str(out)]) == 2
    err = _one_line_error(capsys)
    assert str(synth / "sources.json") in err and LEAKED in err and "DF_080" in err
    assert "1 of the 2 train frames held out in CV fold 2 of 2" in err and "without the held-out roads" in err
    assert not (out / "shared/cv_100.json").exists()


def test_each_cv_fold_checks_before_training(tmp_path):
    """cv_one (what the suite's cv jobs run) refuses the leaking fold itself, and only that one."""
    pytest.importorskip("torch")
    _bench()
    from _perception_arms import Config
    from _perception_cv import cv_one
    from _perception_data import load_frames

    from roadtwin_core.errors import RoadtwinError

    synth_dir = make_standin_synthetic(tmp_path / "synth", n=2)
    (synth_dir / "sources.json").write_text(json.dumps({"frames": [f"{LEAKED}.jpg"]}))   # extension ignored
    real = load_frames(TINY / "train", (64, 40))
    synth = load_frames(synth_dir, (64, 40))
    cfg = Config(steps=1, pretrain_steps=1, batch=2, lr=1e-3, width=4, encoder="scratch", subset_seed=0, size=(64, 40))
    point = {"ratio": 0.5, "schedule": "constant"}
    with pytest.raises(RoadtwinError, match="CV fold 2 of 2"):
        cv_one(1.0, point, 1, 2, real, synth, cfg, 2, 0, "cpu", lambda *a: None)
    part = cv_one(1.0, point, 0, 2, real, synth, cfg, 2, 0, "cpu", lambda *a: None)   # RS_290 only: clean
    assert part["leak_checked"] is True and part["held_out"] == ["RS_290"] and part["steps"] == 2


def test_a_set_without_train_frames_runs_and_an_unknown_one_says_so(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    from _perception_cv import leak_guard
    from _perception_data import Frames

    synth = make_standin_synthetic(tmp_path / "synth")
    val_stem = sorted(p.stem for p in (TINY / "val/images").iterdir())[0]
    (synth / "sources.json").write_text(json.dumps({"frames": [val_stem]}))      # a val frame: not a CV fold's
    out = tmp_path / "o"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *CV_ARGS, "--out", str(out)]) == 0
    rec = json.loads((out / "shared/cv_100.json").read_text())
    assert rec["leak_checked"] is True and rec["synthetic"] == str(synth)
    (tmp_path / "r.json").write_text(json.dumps(rec))
    assert bench.main(["choose-set", str(tmp_path / "r.json"), "--out", str(tmp_path / "choice.json")]) == 0
    assert json.loads((tmp_path / "choice.json").read_text())["scores"][str(synth)]["leak_checked"] is True

    lines = []
    blank = Frames(np.zeros((4, 2, 2, 3), np.uint8), np.zeros((4, 2, 2), np.uint8), TRAIN_STEMS, str(TINY / "train"))
    unknown = Frames(blank.images, blank.labels, ["x"], str(tmp_path / "no_provenance"))
    assert leak_guard([1.0], blank, unknown, bench.config_of(bench.build_parser().parse_args(
        ["train", "--out", "x", "--encoder", "scratch"])), 2, lines.append) is False
    assert len(lines) == 1 and "no sources.json" in lines[0] and "unknown" in lines[0]


def _asset(path: Path, name: str, source: str) -> None:
    from roadtwin_core import DefectModel
    from roadtwin_core.usd import write_defect_asset

    verts = np.array([[0, 0, 0], [0.4, 0, 0], [0.4, 0.3, 0], [0, 0.3, 0], [0.2, 0.15, -0.04]], float)
    faces = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    write_defect_asset(DefectModel(name, "pothole", verts, faces, np.array([0, 1, 2, 3]), source=source), path)


def _town(town: Path, placed: list[str]) -> None:
    """A composed town's defects layer (what roadtwin_core/usd/town.py writes): one instance per
    placed asset, its roadtwin:source the library file relative to layers/."""
    (town / "layers").mkdir(parents=True)
    layer = Sdf.Layer.CreateNew(str(town / "layers/defects.usda"))
    Sdf.CreatePrimInLayer(layer, "/Town/Defects")
    for i, name in enumerate(placed):
        prim = Sdf.CreatePrimInLayer(layer, f"/Town/Defects/d{i}")
        prim.specifier = Sdf.SpecifierDef
        Sdf.AttributeSpec(prim, "roadtwin:source", Sdf.ValueTypeNames.Asset).default = Sdf.AssetPath(f"../library/{name}.usda")
    layer.Save()


def test_sources_json_lists_the_frames_of_placed_photo_assets_and_worn_road_materials(tmp_path):
    """A hand-made composed town: photo assets a (frame A, placed twice) and b (frame B, NOT
    placed), a parametric asset c (placed); road materials m0 (quilted from P and Q) and m1 (R),
    the town scene wearing names[road_photo 2 % 2] = m0. Expected by hand: {A, P, Q}."""
    ss = _synthetic_set()
    out = tmp_path / "set"
    work = out / "scenes" / "town"
    lib = work / "town" / "library"
    lib.mkdir(parents=True)
    frame_a = "/data/my photos/1050564_DF_080_080BDF0050_1_00368.jpg"
    _asset(lib / "a.usda", "a", f"photo {frame_a} (pothole instance 3); license: MIT (Passos et al.)")
    _asset(lib / "b.usda", "b", "photo /data/917067_RS_290_290RS294095_18785.jpg (crack instance 1); license: MIT")
    _asset(lib / "c.usda", "c", "parametric")
    _town(work / "town", ["a", "c", "a"])
    mats = tmp_path / "surfaces"
    mats.mkdir()
    (mats / "materials.json").write_text(json.dumps({"materials": [
        {"name": "m0", "frame": "/d/P_1.jpg", "sources": [{"frame": "/d/P_1.jpg"}, {"frame": "/d/Q_2.jpg"}]},
        {"name": "m1", "frame": "/d/R_3.jpg"}]}))
    args = argparse.Namespace(road_textures=mats, no_road_textures=False)
    scene = next(s for s in ss.SCENES if s.name == "town")
    assert scene.road_photo == 2
    ss.record_scene_sources(scene, args, work)
    images = out / "synthetic" / "images"
    images.mkdir(parents=True)
    (images / "town_000000.jpg").write_bytes(b"")
    path = ss.write_set_sources(out)
    rec = json.loads(path.read_text())
    assert rec["frames"] == ["1050564_DF_080_080BDF0050_1_00368", "P_1", "Q_2"]
    assert rec["scenes"]["town"] == {"defect_assets": {"a": "1050564_DF_080_080BDF0050_1_00368"},
                                     "road_materials": {"m0": ["P_1", "Q_2"]}}
    first = path.read_bytes()
    ss.write_set_sources(out)
    assert path.read_bytes() == first                        # same inputs, same bytes

    no_photo = argparse.Namespace(road_textures=mats, no_road_textures=True)   # --no-road-textures: none worn
    ss.record_scene_sources(scene, no_photo, work)
    assert json.loads(ss.write_set_sources(out).read_text())["frames"] == ["1050564_DF_080_080BDF0050_1_00368"]

    (images / "town01_000000.jpg").write_bytes(b"")         # a scene packed without a provenance record
    lines = []
    assert ss.write_set_sources(out, lines.append) is None and not path.exists()
    assert len(lines) == 1 and "town01" in lines[0]


def test_a_run_records_the_train_frames_beyond_its_fraction_the_set_was_made_from(tmp_path, capsys):
    """A mixed run at 50 % of the tiny train (2 of 4 frames) with a set made from all four train
    frames: the two outside the subset gave labels the arm is not given; at 100 % none; a set
    without provenance: unknown (None)."""
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    (synth / "sources.json").write_text(json.dumps({"frames": [f"{s}.jpg" for s in TRAIN_STEMS] + ["elsewhere_1"]}))
    args = ["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "c", "--mix", "0.5:constant",
            "--seeds", "0", "--fractions", "0.5", "1", "--out", str(tmp_path / "o")]
    assert bench.main(args) == 0
    runs = {json.loads(p.read_text())["name"]: json.loads(p.read_text()) for p in (tmp_path / "o").glob("run_*.json")}
    assert len(TRAIN_STEMS) == 4 and runs["mixed@50%"]["real_frames"] == 2
    assert runs["mixed@50%"]["synthetic_from_train_beyond_fraction"] == 2
    assert runs["mixed@100%"]["synthetic_from_train_beyond_fraction"] == 0
    assert "made from 2 train frames outside this 50 % subset" in capsys.readouterr().out
    (synth / "sources.json").unlink()
    assert bench.main(args[:-1] + [str(tmp_path / "o2")]) == 0
    assert {json.loads(p.read_text())["synthetic_from_train_beyond_fraction"] for p in (tmp_path / "o2").glob("run_*.json")} == {None}
