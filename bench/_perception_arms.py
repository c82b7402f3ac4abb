"""The arms of bench/perception.py and one run of an arm. Every arm runs two phases of P and R
steps (each a fresh AdamW, warm-up + cosine), so all arms spend the same P + R optimizer steps:

  real     (a) P real + R real
  pretrain (b) P synthetic + R real (the P-step synthetic model is shared per seed: --cache)
  mixed    (c) P mixed + R mixed ("constant") or R real ("finetune"); every mixed batch holds
               round(ratio * batch) synthetic frames and the rest real; ratio and schedule come
               from the cross-validation over the train frames (bench/_perception_cv.py) or --mix
  paste    (d) P + R real with real pothole pixels pasted into other real frames (same rows)
  zeroshot (e) P synthetic + R synthetic: never sees a real frame (no fraction); with
               --pseudo-labels KEEP, R on the real train images pseudo-labelled by the P-step
               model (never their labels) mixed 1:1 with synthetic frames (bench/_pseudo_labels.py)

Phase 2 of (a), (b) and a "finetune" (c) draw the same real batches (same phase seed).
``bn_stats="real"`` (``--bn-stats real``): after phase 2 every arm's batch-norm statistics are
recomputed on its real train frames (AdaBN; zero-shot: the train images, never their labels);
the run is evaluated with the trained statistics first (``as_trained`` in its JSON): the same
weights both ways, so the report gives AdaBN's own effect, paired, without training twice.
``domain_bn`` (``--domain-bn``): arms (b) and (c) train with a batch-norm pair per layer, one
for real and one for synthetic frames (DSBN, bench/_domain_bn.py); evaluation uses the real one.
Nothing is selected on the evaluation frames: fixed schedules, the last weights.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from roadtwin_core.datasets import IGNORE_INDEX
from roadtwin_core.errors import RoadtwinError

import _segnet
from _perception_data import CLASSES, Frames, real_subset
from _domain_bn import split_batchnorms
from _pseudo_labels import pseudo_labels
from _perception_train import MEAN, STD, Phase, evaluate, recalibrate_bn, to_device, train_phase

ARMS = ("real", "pretrain", "mixed", "paste", "zeroshot")
BN_STATS = ("train", "real")
LETTER = dict(zip(ARMS, "abcde"))
SYNTHETIC_ARMS = ("pretrain", "mixed", "zeroshot")
SCHEDULES = ("constant", "finetune")


@dataclass
class Config:
    steps: int = 2250             # R: phase-2 steps
    pretrain_steps: int = 2250    # P: phase-1 steps
    batch: int = 16
    lr: float = 2e-3
    weight_decay: float = 1e-4
    width: int = 32               # scratch: U-Net base channels; efficientnet-lite0: decoder width x width/32
    encoder: str = _segnet.DEFAULT_ENCODER
    warmup: int = 100
    subset_seed: int = 0
    size: tuple | None = (512, 320)
    style: str | None = None      # "fda:BETA": synthetic frames take real frames' low frequencies
    bn_stats: str = "train"       # "real": BN statistics recomputed on the arm's real train frames after training
    domain_bn: bool = False       # (b), (c): a BN pair per layer, real and synthetic frames apart (bench/_domain_bn.py)
    pseudo_keep: float | None = None  # (e): phase 2 on pseudo-labelled real train images + synthetic (bench/_pseudo_labels.py)
    encoder_lr: float = 1.0       # the ImageNet encoder's learning rate as a share of lr (0: frozen)


def run_name(arm: str, fraction: float | None) -> str:
    return arm if arm == "zeroshot" else f"{arm}@{round(fraction * 100):g}%"


def make_model(cfg: Config):
    """The network of ``cfg.encoder`` (bench/_segnet.py); a missing encoder package is one line."""
    try:
        return _segnet.make_model(cfg.encoder, cfg.width, len(CLASSES), MEAN, STD)
    except _segnet.EncoderUnavailable as exc:
        raise RoadtwinError(str(exc)) from None


def fresh_model(cfg: Config, seed: int, device, domains: bool = False):
    """The seed's initial network; ``domains``: its BNs split into real / synthetic pairs."""
    torch = _segnet_torch()
    torch.manual_seed(seed)                    # the same initial weights in every arm of a seed
    m = make_model(cfg)
    if domains:
        split_batchnorms(m)
    m = m.to(device)
    if torch.device(device).type == "cuda":
        m = m.to(memory_format=torch.channels_last)
    return m


def _segnet_torch():
    import torch

    return torch


def mix_counts(batch: int, ratio: float) -> dict:
    """Frames per source of a mixed batch: at least one of each."""
    n_syn = min(batch - 1, max(1, int(round(ratio * batch))))
    return {"real": batch - n_syn, "synth": n_syn}


def arm_phases(arm: str, cfg: Config, seed: int, mix: dict | None = None) -> list[Phase]:
    P, R, B = cfg.pretrain_steps, cfg.steps, cfg.batch
    real, synth = {"real": B}, {"synth": B}
    s1, s2 = seed * 1000 + 1, seed * 1000 + 3
    if arm == "real":
        return [Phase("real phase 1", P, real, seed=seed * 1000 + 2), Phase("real", R, real, seed=s2)]
    if arm == "pretrain":
        return [Phase("synthetic", P, synth, seed=s1), Phase("real", R, real, seed=s2)]
    if arm == "zeroshot" and cfg.pseudo_keep:
        return [Phase("synthetic", P, synth, seed=s1),
                Phase("pseudo-labelled real + synthetic", R, mix_counts(B, 0.5), seed=seed * 1000 + 4)]
    if arm == "zeroshot":
        return [Phase("synthetic", P, synth, seed=s1), Phase("synthetic phase 2", R, synth, seed=seed * 1000 + 4)]
    if arm == "paste":
        return [Phase("paste phase 1", P, real, paste=True, seed=seed * 1000 + 2),
                Phase("paste", R, real, paste=True, seed=s2)]
    if arm == "mixed":
        counts = mix_counts(B, mix["ratio"])
        second = counts if mix["schedule"] == "constant" else real
        return [Phase("mixed", P, counts, seed=seed * 1000 + 5),
                Phase("mixed" if second is counts else "real", R, second, seed=s2 if second is real else seed * 1000 + 6)]
    raise RoadtwinError(f"--arms: {arm!r} is not one of {', '.join(ARMS)}")


def pretrained_synthetic(cfg: Config, seed: int, synth_dev, device, cache: Path | None, log=print, style_dev=None,
                         domains: bool = False):
    """The P-step synthetic model of a seed (phase 1 of (b) and (e)): loaded from ``cache`` when
    a run already made it, else trained (and saved there, atomically). ``domains``: with a BN pair
    per layer (``--domain-bn``, arm (b)); phase 1 trains the synthetic ones."""
    torch = _segnet_torch()
    phase = arm_phases("pretrain", cfg, seed)[0]
    style = f"_{cfg.style.replace(':', '')}_r{style_dev.shape[0]}" if cfg.style and style_dev is not None else ""
    key = (f"pretrain_seed{seed}_{cfg.encoder}_w{cfg.width}_P{cfg.pretrain_steps}_b{cfg.batch}"
           f"_n{synth_dev[0].shape[0]}{style}{'_dsbn' if domains else ''}"
           f"{f'_elr{cfg.encoder_lr:g}' if cfg.encoder_lr != 1 else ''}.pt")
    model = fresh_model(cfg, seed, device, domains)
    path = Path(cache) / key if cache else None
    if path is not None and path.exists():
        saved = torch.load(path, map_location=device, weights_only=False)
        model.load_state_dict(saved["state"])
        log(f"  loaded the synthetic phase 1 of seed {seed} from {path}")
        return model, saved["phase"]
    data = {"synth": synth_dev, **({"style": style_dev} if style_dev is not None else {})}
    info = train_phase(model, data, phase, cfg, device, log)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{id(model)}")
        torch.save({"state": model.state_dict(), "phase": info}, tmp)
        tmp.replace(path)
    return model, info


def train_arm(arm: str, cfg: Config, seed: int, real: Frames | None, synth: Frames | None, device,
              mix: dict | None = None, cache: Path | None = None, log=print, style: Frames | None = None,
              adapt: bool = True):
    """The model of one arm, trained; returns (model, phases info). With ``cfg.style``, the
    synthetic frames take their low frequencies from ``style``'s images (real frames the arm
    may see; their labels are never read). ``adapt``: apply ``cfg.bn_stats`` (see adapt_bn)."""
    phases = arm_phases(arm, cfg, seed, mix)
    data = {}
    if real is not None and arm in ("real", "pretrain", "mixed", "paste"):
        data["real"] = to_device(real, device)
    if arm in SYNTHETIC_ARMS:
        if synth is None:
            raise RoadtwinError(f"--arms {arm}: needs --synthetic DIR")
        data["synth"] = to_device(synth, device)
        if cfg.style and style is not None:
            data["style"] = to_device(style, device)[0]
    if arm in ("pretrain", "zeroshot"):
        model, first = pretrained_synthetic(cfg, seed, data["synth"], device, cache, log, data.get("style"),
                                            domains=cfg.domain_bn and arm == "pretrain")
        infos = [first]
        if arm == "zeroshot" and cfg.pseudo_keep:
            adapt_with_pseudo_labels(model, cfg, style, data, device, infos)
    else:
        model = fresh_model(cfg, seed, device, domains=cfg.domain_bn and arm == "mixed")
        infos = [train_phase(model, data, phases[0], cfg, device, log)]
    infos.append(train_phase(model, data, phases[1], cfg, device, log))
    if adapt:
        adapt_bn(model, cfg, arm, real, style, device, infos)
    return model, infos


def adapt_with_pseudo_labels(model, cfg: Config, style: Frames | None, data: dict, device, infos: list) -> None:
    """Zero-shot with ``cfg.pseudo_keep`` (CBST): the real train images, never their labels,
    labelled by the phase-1 model (per class its most confident ``pseudo_keep`` share), become
    the "real" source of phase 2."""
    if style is None:
        raise RoadtwinError("--pseudo-labels: the zero-shot arm has no real train images to label")
    torch = _segnet_torch()
    images = torch.from_numpy(np.ascontiguousarray(style.images)).to(device)    # the images only
    labels, info = pseudo_labels(model, images, device, cfg.batch, cfg.pseudo_keep, IGNORE_INDEX)
    data["real"] = (images, labels)
    infos[-1] = {**infos[-1], "pseudo_labels": info}


def adapt_bn(model, cfg: Config, arm: str, real: Frames | None, style: Frames | None, device, infos: list) -> None:
    """With ``cfg.bn_stats == "real"``, AdaBN: the model's batch-norm statistics recomputed on the
    arm's real train frames (zero-shot: the train images ``style``, never their labels), noted in
    the last phase's info. Every arm alike."""
    if cfg.bn_stats != "real":
        return
    frames = real if real is not None else style
    if frames is None:
        raise RoadtwinError(f"--bn-stats real: arm {arm} has no real train frames to take the statistics from")
    layers = recalibrate_bn(model, to_device(frames, device)[0], device, cfg.batch)
    infos[-1] = {**infos[-1], "bn_stats": {"from": "real train frames", "frames": len(frames.stems), "layers": layers}}


def run_arm(arm: str, fraction: float | None, seed: int, real: Frames, evalset: Frames, synth: Frames | None,
            cfg: Config, device, mix: dict | None = None, cache: Path | None = None, keep=(), log=print,
            selectset: Frames | None = None) -> dict:
    """One (arm, fraction, seed) run: train, evaluate per frame; the result a run JSON holds.
    ``selectset``: the same model also evaluated there (``select``), for choices val must not make."""
    t0 = time.perf_counter()
    sub = real_subset(real, fraction, cfg.subset_seed) if arm != "zeroshot" else None
    # the style frames: the arm's real frames; zero-shot sees no real label, only the train images
    style = sub if sub is not None else real
    model, infos = train_arm(arm, cfg, seed, sub, synth, device, mix, cache, log, style=style, adapt=False)
    t1 = time.perf_counter()
    evaldev = to_device(evalset, device)
    as_trained = None
    if cfg.bn_stats == "real":   # the same weights evaluated with their trained statistics first: a paired AdaBN effect
        i, u, _ = evaluate(model, evaldev, device, cfg.batch)
        as_trained = {"I": i.tolist(), "U": u.tolist()}
        adapt_bn(model, cfg, arm, sub, style, device, infos)
    i, u, kept = evaluate(model, evaldev, device, cfg.batch, set(keep))
    select = None
    if selectset is not None:
        si, su, _ = evaluate(model, to_device(selectset, device), device, cfg.batch)
        select = {"folder": selectset.folder, "stems": selectset.stems, "I": si.tolist(), "U": su.tolist()}
    steps = sum(p["steps"] for p in infos)
    train_s = sum(p["seconds"] for p in infos)
    return {"arm": arm, "letter": LETTER[arm], "fraction": fraction if arm != "zeroshot" else None, "seed": seed,
            "name": run_name(arm, fraction), "config": asdict(cfg), "mix": mix, "phases": infos, "steps": steps,
            "train_seconds": round(train_s, 2), "steps_per_s": round(steps / train_s, 2) if train_s else None,
            "eval_seconds": round(time.perf_counter() - t1, 2), "wall_seconds": round(time.perf_counter() - t0, 2),
            "real_frames": len(sub.stems) if sub else 0, "real_pothole_frames": int(len(sub.pothole_frames())) if sub else 0,
            "synthetic_frames": len(synth.stems) if synth is not None and arm in SYNTHETIC_ARMS else 0,
            "eval": {"folder": evalset.folder, "stems": evalset.stems},
            "I": i.tolist(), "U": u.tolist(), **({"as_trained": as_trained} if as_trained else {}),
            **({"select": select} if select else {}),
            "grid": {str(k): v for k, v in sorted(kept.items())}}


def write_run(result: dict, out: Path) -> Path:
    """OUT/run_<arm>_<pct>_seed<k>.json (+ .npz of the grid predictions), written atomically."""
    out.mkdir(parents=True, exist_ok=True)
    pct = "na" if result["fraction"] is None else f"{round(result['fraction'] * 100):g}"
    base = out / f"run_{result['arm']}_{pct}_seed{result['seed']}"
    grid = result.pop("grid")
    tmp = base.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, frames=np.array([int(k) for k in grid], dtype=np.int64),
                        preds=np.stack(list(grid.values())) if grid else np.zeros((0, 1, 1), np.uint8))
    tmp.replace(base.with_suffix(".npz"))
    tmp = base.with_suffix(".tmp.json")
    tmp.write_text(json.dumps(result))
    tmp.replace(base.with_suffix(".json"))
    return base.with_suffix(".json")
