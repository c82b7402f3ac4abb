"""Class maps, dataset folders and the survey rig estimate on CPU (the benchmark itself,
bench/perception.py: tests/core/test_perception_bench.py)."""
from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from roadtwin_core import RoadtwinError
from roadtwin_core.datasets.folders import find_pairs, load_folder
from roadtwin_core.render.classmap import builtin_class_maps, load_class_map, parse_class_map
from roadtwin_core.render.scene import class_names

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests/data/road_defects_br_tiny"


# ---------------------------------------------------------------------------------- class map
STAGE = class_names(["pothole", "crack", "bump", "rut", "manhole", "depression"])
# -> background 0, driving 1, junction 2, sidewalk 3, shoulder 4, bump 5, crack 6,
#    depression 7, manhole 8, pothole 9, rut 10


def test_builtin_class_map_matches_the_real_classes_and_is_package_data():
    m = load_class_map("road_defects_br")
    assert m.classes == ("background", "ego_lane", "crack", "pothole")
    assert "road_defects_br" in builtin_class_maps()
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    globs = cfg["tool"]["setuptools"]["package-data"]["roadtwin_core.render"]
    shipped = [p for g in globs for p in (ROOT / "roadtwin_core/render").glob(g)]
    assert ROOT / "roadtwin_core/render/classmaps/road_defects_br.toml" in shipped
    m.check_labels(STAGE)      # every label it names exists in a stage with the standard defect types


def test_class_map_on_a_hand_made_label_array_with_an_ego_mask():
    assert STAGE[:5] == ["background", "driving", "junction", "sidewalk", "shoulder"]
    sid = {n: i for i, n in enumerate(STAGE)}
    labels = np.array([[sid["background"], sid["driving"], sid["driving"], sid["sidewalk"]],
                       [sid["pothole"], sid["pothole"], sid["crack"], sid["manhole"]],
                       [sid["shoulder"], sid["rut"], 255, sid["driving"]]], dtype=np.uint8)
    ego = np.array([[1, 1, 0, 1],
                    [1, 0, 1, 1],
                    [1, 1, 1, 0]], dtype=bool)
    # dataset ids: 0 background, 1 ego_lane, 2 crack, 3 pothole. Defects win over the lane,
    # road surface inside the ego mask is ego lane, a manhole/rut outside it is background.
    expected = np.array([[0, 1, 0, 0],
                         [3, 3, 2, 1],
                         [0, 1, 255, 0]], dtype=np.uint8)
    m = load_class_map("road_defects_br")
    assert np.array_equal(m.apply(labels, STAGE, ego), expected)
    # without a frame's ego mask there is no ego lane
    no_ego = expected.copy()
    no_ego[no_ego == 1] = 0
    assert np.array_equal(m.apply(labels, STAGE), no_ego)


def test_class_map_unknown_ignore_and_bad_maps(tmp_path):
    m = parse_class_map('classes = ["bg", "hole"]\nunknown = "ignore"\n[map]\nbg = ["background"]\nhole = ["pothole"]\n')
    sid = {n: i for i, n in enumerate(STAGE)}
    out = m.apply(np.array([sid["background"], sid["pothole"], sid["driving"]], np.uint8), STAGE)
    assert out.tolist() == [0, 1, 255]
    path = tmp_path / "mine.toml"
    path.write_text('classes = ["bg", "hole"]\n[map]\nbg = ["background"]\nhole = ["potholes"]\n')
    with pytest.raises(RoadtwinError) as err:
        load_class_map(path).check_labels(STAGE, "town.usda")
    msg = str(err.value)
    assert "'potholes'" in msg and str(path) in msg and "town.usda" in msg and "\n" not in msg
    for text, word in [('classes = ["a"]\n[map]\nb = ["x"]\n', "'b'"),
                       ('classes = ["a", "b"]\n[map]\na = ["x"]\nb = ["x"]\n', "'x'"),
                       ('classes = ["a"]\n[map]\na = {from = ["x"], rule = "left"}\n', "'left'"),
                       ('classes = ["a"\n', "TOML")]:
        with pytest.raises(RoadtwinError, match=word):
            parse_class_map(text, "f.toml")
    with pytest.raises(RoadtwinError, match="no class map 'nope'"):
        load_class_map("nope")


def test_label_range_ignores_only_far_pixels_of_the_named_classes():
    """[label_range_m]: crack pixels deeper than 8 m and pothole pixels deeper than 15 m become
    ignore; nearer ones, other classes and pixels without a hit (depth 0) keep their class."""
    m = parse_class_map('classes = ["bg", "lane", "crack", "hole"]\n[map]\nbg = ["background"]\ncrack = ["crack"]\n'
                        'hole = ["pothole"]\n[label_range_m]\ncrack = 8\nhole = 15.0\n')
    mapped = np.array([[2, 2, 3, 3, 1, 0]], np.uint8)
    depth = np.array([[7.9, 8.1, 14.9, 15.1, 40.0, 0.0]], np.float32)
    assert m.within_range(mapped, depth).tolist() == [[2, 255, 3, 255, 1, 0]]
    assert load_class_map("road_defects_br").label_range_m == ()          # opt-in: the built-in map labels every distance
    for text, word in [('classes = ["a"]\n[map]\na = ["x"]\n[label_range_m]\nb = 3\n', "'b'"),
                       ('classes = ["a"]\n[map]\na = ["x"]\n[label_range_m]\na = -1\n', "metres > 0")]:
        with pytest.raises(RoadtwinError, match=word):
            parse_class_map(text, "f.toml")


# ------------------------------------------------------------------------------ dataset folders
def _write_pair(root: Path, stem: str, label: np.ndarray, img_ext=".jpg", sub=("images", "labels")):
    (root / sub[0]).mkdir(parents=True, exist_ok=True)
    (root / sub[1]).mkdir(parents=True, exist_ok=True)
    h, w = label.shape
    Image.fromarray(np.full((h, w, 3), 100, np.uint8)).save(root / sub[0] / f"{stem}{img_ext}")
    Image.fromarray(label.astype(np.uint8)).save(root / sub[1] / f"{stem}.png")


def test_dataset_folder_bad_inputs(tmp_path):
    ok = np.zeros((8, 12), np.uint8)
    unpaired = tmp_path / "unpaired"
    _write_pair(unpaired, "a", ok)
    _write_pair(unpaired, "b", ok)
    (unpaired / "labels/b.png").rename(unpaired / "labels/c.png")
    with pytest.raises(RoadtwinError) as err:
        find_pairs(unpaired)
    msg = str(err.value)
    assert str(unpaired) in msg and "images/b.jpg" in msg and "labels/c.png" in msg and "\n" not in msg

    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    (empty / "labels").mkdir()
    with pytest.raises(RoadtwinError, match="empty"):
        find_pairs(empty)
    with pytest.raises(RoadtwinError, match="not a dataset folder"):
        find_pairs(tmp_path / "empty" / "images")
    with pytest.raises(RoadtwinError, match="no such"):
        find_pairs(tmp_path / "missing")

    bad = tmp_path / "bad"
    lab = ok.copy()
    lab[3, 4] = 7
    _write_pair(bad, "x", lab)
    with pytest.raises(RoadtwinError) as err:
        load_folder(bad, num_classes=4)
    assert "x.png" in str(err.value) and "7" in str(err.value)

    small = tmp_path / "small"
    _write_pair(small, "y", ok)
    Image.fromarray(np.zeros((4, 6), np.uint8)).save(small / "labels/y.png")
    with pytest.raises(RoadtwinError, match="6x4"):
        load_folder(small, num_classes=4)


def test_dataset_folder_reads_both_layouts(tmp_path):
    lab = np.zeros((8, 12), np.uint8)
    lab[2:5, 3:9] = 3
    lab[0, 0] = 255                                    # ignore is allowed
    _write_pair(tmp_path / "out/mmseg", "000001", lab, ".png", ("img_dir/train", "ann_dir/train"))
    _write_pair(tmp_path / "out/mmseg", "000000", lab, ".png", ("img_dir/train", "ann_dir/train"))
    pairs = find_pairs(tmp_path / "out")               # a render output root
    assert [p.stem for p in pairs] == ["train/000000", "train/000001"]
    (tmp_path / "out/images").mkdir()                  # ... which also holds RGB previews in images/
    Image.fromarray(np.zeros((8, 12, 3), np.uint8)).save(tmp_path / "out/images/000000.png")
    assert [p.stem for p in find_pairs(tmp_path / "out")] == ["train/000000", "train/000001"]
    images, labels, stems = load_folder(tmp_path / "out", 4)
    assert images.shape == (2, 8, 12, 3) and np.array_equal(labels[1], lab)
    real = find_pairs(TINY / "train")
    assert len(real) == 4 and all(p.image.suffix == ".jpg" for p in real)
    torch = pytest.importorskip("torch")
    from roadtwin_core.datasets.folders import SegmentationFolder

    item = SegmentationFolder(TINY / "val", 4)[1]
    ref = np.asarray(Image.open(sorted((TINY / "val/labels").glob("*.png"))[1]))
    assert item["image"].shape == (3, 320, 512) and item["image"].dtype == torch.float32
    assert np.array_equal(item["label"].numpy(), ref)


# ------------------------------------------------------------------------------- survey rig
def test_survey_rig_estimate_recovers_a_known_camera():
    """Label a 3.5 m lane seen by a known camera (ray-plane intersection through cameras.py),
    then estimate: the horizon/width-slope geometry must give back height and pitch."""
    import math

    from roadtwin_core.render.cameras import RIG_PRESETS, Camera, Intrinsics, look_from

    spec = importlib.util.spec_from_file_location("estimate_survey_rig", ROOT / "bench/estimate_survey_rig.py")
    est = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(est)
    k = Intrinsics.from_fov(512, 320, 60.0)
    cam = Camera(k, look_from((0.0, 0.4, 2.3), 0.0, math.radians(-25.0)))
    d, o = cam.rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
    y = o[1] + t * d[..., 1]
    label = (np.isfinite(t) & (np.abs(y) < 1.75)).astype(np.uint8)
    e = est.frame_estimate(label)
    rig = est.rig_from(e["v_h"], e["slope"], e["u_vp"], 512, 320, 60.0, 3.5)
    assert rig["height_m"] == pytest.approx(2.3, rel=0.02)
    assert rig["pitch_down_deg"] == pytest.approx(25.0, abs=0.3)
    assert abs(rig["yaw_deg"]) < 0.3
    survey = RIG_PRESETS["survey"]
    assert (survey.width, survey.height) == (512, 320) and survey.intrinsics().fx == pytest.approx(k.fx)
    assert RIG_PRESETS["stereo"].baseline_m == 0.54


def test_lane_coordinates_of_single_points_match_the_closed_form():
    """A camera's arc length along its lane (taken for every device-finished frame, without a
    k-d tree for a few points): on an L-shaped centreline, the closed-form foot of the
    perpendicular; the same numbers as the k-d tree's path for many points."""
    import roadtwin_core.render.ego_lane as ego

    lane = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 40.0]])
    pts = np.array([[12.3, 1.1], [29.0, -0.5], [31.2, 25.0], [-2.0, 0.4], [30.5, 44.0]])
    want_s = [12.3, 29.0, 55.0, 0.0, 70.0]
    want_lat = [1.1, -0.5, -1.2, 0.4, 0.5]
    want_inside = [True, True, True, False, False]
    for p, s, lat, inside in zip(pts, want_s, want_lat, want_inside):
        got = ego.lane_coordinates(p[None], lane)
        assert got[0][0] == pytest.approx(s, abs=1e-9) and got[2][0] == inside
        if inside:
            assert got[1][0] == pytest.approx(lat, abs=1e-9)
    rng = np.random.default_rng(1)
    many = rng.uniform([-5, -5], [35, 45], (5000, 2))          # beyond the brute-force size: the k-d tree
    assert len(many) * 300 > ego.BRUTE_FORCE_PAIRS
    tree = ego.lane_coordinates(many, lane)
    one_by_one = [ego.lane_coordinates(p[None], lane) for p in many[:200]]
    for i, got in enumerate(one_by_one):
        assert all(g[0] == t[i] for g, t in zip(got, tree))
