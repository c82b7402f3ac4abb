"""A leak-free CV for issue 21's mixed arm: ``perception.py frames`` lists the train frames a fair
photo set may be made from (per fraction its subset, per CV fold that subset less the fold's
held-out frames), and ``--cv-synthetic DIR0 DIR1 ...`` gives each fold its own set, each checked
against its own fold only.

The tiny train (tests/data/road_defects_br_tiny): roads RS_290 (2 frames), DF_080 (1), DF_251
(1). The folds worked out by hand from cv_folds' rule (roads by size, largest first, ties in name
order, each to the least-loaded fold, lowest index on a tie):
  k = 3: RS_290 -> fold 0, DF_080 -> fold 1, DF_251 -> fold 2;
  k = 2: RS_290 -> fold 0, DF_080 -> fold 1 (load 0 < 2), DF_251 -> fold 1 (load 1 < 2).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from test_perception_bench import SMALL, TINY, _bench, make_standin_synthetic

TRAIN = sorted(p.stem for p in (TINY / "train/images").iterdir())
RS_A, RS_B = "917067_RS_290_290RS294095_18785", "941636_RS_290_290RS070691_01085"
DF_080, DF_251 = "1050564_DF_080_080BDF0050_1_00368", "1092937_DF_251_251BDF0052_00833"
CV = ["--arms", "c", "--fractions", "1", "--cv-ratios", "0.5", "--cv-schedules", "constant", "--cv-steps", "2",
      "--cv-only"]


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err, err
    return err


def test_frames_lists_each_fractions_subset_and_each_folds_training_frames(tmp_path):
    bench = _bench()
    assert TRAIN == sorted([RS_A, RS_B, DF_080, DF_251])
    out = tmp_path / "lists"
    assert bench.main(["frames", "--real", str(TINY), "--fractions", "1", "--cv-folds", "3", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frames_100.txt", "frames_100_fold0.txt", "frames_100_fold1.txt",
                                                     "frames_100_fold2.txt"]
    assert _lines(out / "frames_100.txt") == TRAIN
    assert _lines(out / "frames_100_fold0.txt") == [DF_080, DF_251]           # RS_290 held out
    assert _lines(out / "frames_100_fold1.txt") == [DF_251, RS_A, RS_B]       # DF_080 held out
    assert _lines(out / "frames_100_fold2.txt") == [DF_080, RS_A, RS_B]       # DF_251 held out

    # 50 %: the subset is the rule's seeded draw of round(4 * 0.5) = 2 of the sorted stems; one road
    # in it (< 2 folds), so the folds split its frames by a seeded permutation (one frame each)
    half = sorted(TRAIN[i] for i in np.random.default_rng(0).choice(4, size=2, replace=False))
    held_first = half[int(np.random.default_rng(0).permutation(2)[0])]
    assert bench.main(["frames", "--real", str(TINY), "--fractions", "0.5", "--cv-folds", "2", "--out", str(out)]) == 0
    assert _lines(out / "frames_50.txt") == half == [RS_A, RS_B]               # the 50 % arm's frames (test_perception_cv_leak)
    assert _lines(out / "frames_50_fold0.txt") == [s for s in half if s != held_first]
    assert _lines(out / "frames_50_fold1.txt") == [held_first]


def test_frames_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys):
    bench = _bench()
    out = tmp_path / "lists"
    assert bench.main(["frames", "--real", str(TINY), "--fractions", "1", "--cv-folds", "1", "--out", str(out)]) == 2
    assert "--cv-folds 1" in _one_line_error(capsys)
    # 25 %: round(4 * 0.25) = 1 frame (a pothole frame for subset seed 0): nothing to split in 3 folds
    assert bench.main(["frames", "--real", str(TINY), "--fractions", "1", "0.25", "--out", str(out)]) == 2
    assert "--cv-folds 3: only 1 real frame(s) to split" in _one_line_error(capsys)
    assert not out.exists()                                                    # the 100 % lists were not written either


def _fold_sets(tmp_path: Path, sources: list[list[str]]) -> list[Path]:
    dirs = []
    for k, frames in enumerate(sources):
        d = make_standin_synthetic(tmp_path / f"fold{k}", n=2)
        (d / "sources.json").write_text(json.dumps({"frames": frames}))
        dirs.append(d)
    return dirs


def test_cv_trains_each_fold_with_its_own_set_and_refuses_a_set_holding_its_fold(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    final = make_standin_synthetic(tmp_path / "final", n=2)
    (final / "sources.json").write_text(json.dumps({"frames": TRAIN}))        # the 100 % set: every train frame
    # folds at k = 2 (by hand, module docstring): fold 0 holds out RS_290, fold 1 DF_080 + DF_251
    fair = _fold_sets(tmp_path / "fair", [[DF_080, DF_251], [RS_A, RS_B]])
    out = tmp_path / "o"
    args = ["train", "--real", str(TINY), "--synthetic", str(final), *SMALL, *CV, "--cv-folds", "2"]
    assert bench.main([*args, "--cv-synthetic", *map(str, fair), "--out", str(out)]) == 0
    rec = json.loads((out / "shared/cv_100.json").read_text())
    assert rec["leak_checked"] is True and rec["synthetic"] == str(final) and rec["cv_synthetic"] == list(map(str, fair))
    assert rec["synthetic_from_train_beyond_folds"] == [0, 0]
    # the single final set would leak (every train frame): refused without the per-fold sets
    assert bench.main([*args, "--out", str(tmp_path / "o_single")]) == 2
    assert "CV fold 1 of 2" in _one_line_error(capsys)
    # the fair sets in the wrong order: fold 0 trains with a set made from RS_290, its held-out road
    swapped = list(map(str, fair[::-1]))
    assert bench.main([*args, "--cv-synthetic", *swapped, "--out", str(tmp_path / "o2")]) == 2
    err = _one_line_error(capsys)
    assert f"{fair[1] / 'sources.json'}" in err and "CV fold 1 of 2 (--cv-synthetic folder 0)" in err and "RS_290" in err
    assert not (tmp_path / "o2/shared/cv_100.json").exists()
    # a set holding other folds' frames only (here: every frame but its held-out road's) runs
    other = _fold_sets(tmp_path / "other", [[DF_080, DF_251, "a_val_frame"], [RS_B]])
    assert bench.main([*args, "--cv-synthetic", *map(str, other), "--out", str(tmp_path / "o3")]) == 0
    assert json.loads((tmp_path / "o3/shared/cv_100.json").read_text())["leak_checked"] is True
    # a CV choice already in --out, made with other sets, is not taken for this call's
    assert bench.main([*args, "--cv-synthetic", *map(str, other), "--out", str(out)]) == 2
    assert f"{out / 'shared/cv_100.json'}: a CV choice made with per-fold sets {fair[0]}" in _one_line_error(capsys)


def test_a_suite_cv_job_loads_each_folds_set(tmp_path):
    """What a suite's cv job runs (cmd_job with the suite's arguments): the per-fold sets, checked."""
    pytest.importorskip("torch")
    bench = _bench()
    final = make_standin_synthetic(tmp_path / "final", n=2)
    sets = _fold_sets(tmp_path, [[DF_080], [RS_A]])
    args = bench.build_parser().parse_args(["suite", "--real", str(TINY), "--synthetic", str(final), *SMALL, *CV,
                                            "--cv-folds", "2", "--cv-synthetic", *map(str, sets), "--out", str(tmp_path / "o")])
    common = tmp_path / "o/shared/suite_args.json"
    common.parent.mkdir(parents=True)
    common.write_text(json.dumps(vars(args)))
    part = tmp_path / "o/shared/cv_parts/cv_100_p0.json"
    bench.cmd_job(str(common), json.dumps({"kind": "cv", "fraction": 1.0, "point": 0, "output": str(part)}))
    rec = json.loads(part.read_text())
    assert rec["leak_checked"] is True and rec["synthetic_by_fold"] == list(map(str, sets))
    assert rec["held_out"] == [["RS_290"], ["DF_080", "DF_251"]] and rec["steps"] == 4
    leaky = _fold_sets(tmp_path / "leaky", [[DF_080], [DF_251]])          # fold 1's set holds DF_251, held out there
    args.cv_synthetic = list(map(str, leaky))
    common.write_text(json.dumps(vars(args)))
    from roadtwin_core.errors import RoadtwinError

    with pytest.raises(RoadtwinError, match=r"CV fold 2 of 2 \(--cv-synthetic folder 1\)"):
        bench.cmd_job(str(common), json.dumps({"kind": "cv", "fraction": 1.0, "point": 0, "output": str(part)}))


def test_cv_synthetic_bad_input_is_one_line(tmp_path, capsys):
    pytest.importorskip("torch")
    bench = _bench()
    final = make_standin_synthetic(tmp_path / "final", n=2)
    good = _fold_sets(tmp_path, [[DF_080], [RS_A]])
    base = ["train", "--real", str(TINY), "--synthetic", str(final), *SMALL, *CV, "--out", str(tmp_path / "o")]
    assert bench.main([*base, "--cv-folds", "3", "--cv-synthetic", *map(str, good)]) == 2
    assert "2 folder(s) for --cv-folds 3" in _one_line_error(capsys)
    odd = make_standin_synthetic(tmp_path / "odd", n=2, classes=["background", "lane", "crack", "pothole"])
    assert bench.main([*base, "--cv-folds", "2", "--cv-synthetic", str(good[0]), str(odd)]) == 2
    err = _one_line_error(capsys)
    assert str(odd / "classes.json") in err and "differ" in err
    assert bench.main([*base, "--fractions", "1", "0.5", "--cv-folds", "2", "--cv-synthetic", *map(str, good)]) == 2
    assert "one --fractions value" in _one_line_error(capsys)
    assert bench.main([*base, "--cv-folds", "2", "--mix", "0.5:constant", "--cv-synthetic", *map(str, good)]) == 2
    assert "no --mix" in _one_line_error(capsys)
    assert not (tmp_path / "o/shared/cv_100.json").exists()
