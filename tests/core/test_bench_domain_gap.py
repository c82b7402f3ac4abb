"""bench/domain_gap.py: KID and FD against closed forms, and a run on the tiny data."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench_script import load_bench_script

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests/data/road_defects_br_tiny"


@pytest.fixture(scope="module")
def gap():
    return load_bench_script("domain_gap")


def test_kid_is_the_unbiased_mmd_of_the_cubic_kernel(gap):
    """One subset holding every row: KID equals MMD^2 written out pair by pair; it is ~0 for two
    samples of one distribution and grows with a shift of the mean."""
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=(7, 3)), rng.normal(0.5, 1, size=(7, 3))
    k = lambda a, b: (a @ b / 3 + 1) ** 3            # noqa: E731
    xx = sum(k(x[i], x[j]) for i in range(7) for j in range(7) if i != j) / 42
    yy = sum(k(y[i], y[j]) for i in range(7) for j in range(7) if i != j) / 42
    xy = sum(k(x[i], y[j]) for i in range(7) for j in range(7)) / 49
    mean, std = gap.kid(x, y, subsets=3, subset_size=7)
    assert mean == pytest.approx(xx + yy - 2 * xy) and std == pytest.approx(0, abs=1e-12)
    same = gap.kid(rng.normal(size=(400, 8)), rng.normal(size=(400, 8)), subsets=20)[0]
    shifted = gap.kid(rng.normal(size=(400, 8)), rng.normal(0.5, 1, size=(400, 8)), subsets=20)[0]
    assert abs(same) < 0.05 * shifted


def test_frechet_distance_of_gaussians(gap):
    """FD(N(0, I), N(m, 4 I)) in d dims = |m|^2 + d (1 + 4 - 2 * 2) = |m|^2 + d, from large samples."""
    rng = np.random.default_rng(2)
    d, m = 4, np.array([1.0, -2.0, 0.5, 0.0])
    fd = gap.frechet(rng.normal(size=(200000, d)), m + 2 * rng.normal(size=(200000, d)))
    assert fd == pytest.approx(float(m @ m) + d, rel=0.02)


def test_road_halves_keep_roads_whole(gap):
    stems = ["1_DF_080_a", "2_DF_080_b", "3_RS_290_c", "4_RS_290_d", "5_RS_291_e"]
    a, b = gap.road_halves(stems)
    assert sorted(np.concatenate([a, b]).tolist()) == list(range(5))
    roads = lambda idx: {stems[i].split("_")[1] + stems[i].split("_")[2] for i in idx}   # noqa: E731
    assert not roads(a) & roads(b)


def test_a_run_on_the_tiny_data(gap, capsys, tmp_path):
    """The command on the tiny data, and its features: the real frames' colour-inverted copies
    are farther from them (KID) than the frames themselves; a missing folder is one line, exit 2."""
    pytest.importorskip("efficientnet_lite_pytorch")
    from PIL import Image

    inverted = tmp_path / "inverted"
    (inverted / "images").mkdir(parents=True)
    (inverted / "labels").mkdir()
    for f in sorted((TINY / "train/images").glob("*.jpg")):
        Image.fromarray(255 - np.array(Image.open(f))).save(inverted / "images" / f.name)
        lab = TINY / "train/labels" / (f.stem + ".png")
        (inverted / "labels" / lab.name).write_bytes(lab.read_bytes())
    assert gap.main(["--real", str(TINY / "train"), "--synthetic", f"inverted={inverted}", "--limit", "4",
                     "--size", "128x80", "--subsets", "5", "--subset-size", "4",
                     "--json", str(tmp_path / "gap.json"), "--plot", str(tmp_path / "gap.png")]) == 0
    out = capsys.readouterr().out
    assert "real, other roads (floor)" in out and "inverted" in out
    import json

    rows = json.loads((tmp_path / "gap.json").read_text())
    assert [r["set"] for r in rows] == ["real, other roads (floor)", "inverted"]
    assert (tmp_path / "gap.png").read_bytes()[:4] == b"\x89PNG"
    from _perception_data import load_frames

    model = gap.encoder()
    real, inv = (gap.features(model, fr.images, fr.labels)[0]
                 for fr in (load_frames(TINY / "train", (128, 80)), load_frames(inverted, (128, 80))))
    assert gap.kid(real, inv, subsets=3, subset_size=4)[0] > gap.kid(real, real, subsets=3, subset_size=4)[0]
    assert gap.main(["--real", str(TINY / "train"), "--synthetic", "nowhere=/no/such/dir"]) == 2
