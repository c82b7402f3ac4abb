"""Training and evaluation of bench/perception.py, all on the device: uint8 frames live there as
tensors, batches are drawn by seeded permutations, augmented (flip, zoom-in crop, colour jitter)
and, for the copy-paste control, given real pothole pixels from another real frame in the same
image rows, shifted sideways. A phase draws each batch from one or two sources (real,
synthetic) in fixed counts, so a mixed batch holds real and synthetic frames every step.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from roadtwin_core.datasets import IGNORE_INDEX

from _domain_bn import set_real_count
from _perception_data import CLASSES, POTHOLE

MEAN, STD = (0.45, 0.45, 0.45), (0.25, 0.25, 0.25)


def _torch():
    import torch

    return torch


@dataclass
class Phase:
    """``steps`` optimizer steps, each batch ``counts[source]`` frames of each source."""
    name: str
    steps: int
    counts: dict                     # {"real": 12, "synth": 4}
    paste: bool = False              # copy-paste real potholes into the real frames
    seed: int = 0
    log: list = field(default_factory=list)


def to_device(frames, device):
    """The frames' images and labels as tensors on ``device``. The suite's processes map the decoded
    frames read-only: a CUDA device gets its own copy anyway, the CPU a writable one (torch does not
    support tensors over read-only memory, and warned so once a job)."""
    torch = _torch()

    def tensor(a):
        a = np.ascontiguousarray(a)
        if not a.flags.writeable and torch.device(device).type == "cpu":
            a = a.copy()
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
            return torch.from_numpy(a).to(device)

    return tensor(frames.images), tensor(frames.labels)


def augment(images_u8, labels_u8, gen, train: bool = True):
    """uint8 (B,H,W,3) + (B,H,W) -> normalized float (B,3,H,W), long labels. Training adds a
    horizontal flip, a random zoom-in crop (scale 1-1.5) and colour jitter, all on the device."""
    torch = _torch()
    F = torch.nn.functional
    dev = images_u8.device
    x = images_u8.permute(0, 3, 1, 2).float().div_(255.0)
    y = labels_u8.long()
    b = x.shape[0]
    if train:
        # the generator lives on the data's device: a CPU draw copied over each step would make
        # the host wait for the GPU every step
        rnd = lambda *s: torch.rand(*s, generator=gen, device=dev)  # noqa: E731
        scale = 1.0 + 0.5 * rnd(b)
        flip = torch.where(rnd(b) < 0.5, -1.0, 1.0)
        span = 1.0 - 1.0 / scale
        tx, ty = (2 * rnd(b) - 1) * span, (2 * rnd(b) - 1) * span
        theta = torch.zeros(b, 2, 3, device=dev)
        theta[:, 0, 0], theta[:, 0, 2] = flip / scale, tx
        theta[:, 1, 1], theta[:, 1, 2] = 1.0 / scale, ty
        grid = F.affine_grid(theta, list(x.shape), align_corners=False)
        x = F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
        y = F.grid_sample(y[:, None].float(), grid, mode="nearest", padding_mode="border",
                          align_corners=False)[:, 0].long()
        bright, contrast = 0.7 + 0.6 * rnd(b, 1, 1, 1), 0.7 + 0.6 * rnd(b, 1, 1, 1)
        sat, gain = 0.6 + 0.8 * rnd(b, 1, 1, 1), 0.92 + 0.16 * rnd(b, 3, 1, 1)
        grey = x.mean(1, keepdim=True)
        x = grey + (x - grey) * sat
        m = x.mean((1, 2, 3), keepdim=True)
        x = ((x - m) * contrast + m) * bright * gain
        x = x.clamp_(0, 1)
    mean, std = _norm(dev)
    return (x - mean) / std, y


_NORM: dict = {}


def _norm(dev):
    """MEAN/STD as device tensors, made once (a host-to-device copy per step stalls the GPU)."""
    if str(dev) not in _NORM:
        torch = _torch()
        _NORM[str(dev)] = (torch.tensor(MEAN, device=dev).view(1, 3, 1, 1), torch.tensor(STD, device=dev).view(1, 3, 1, 1))
    return _NORM[str(dev)]


def copy_paste(images, labels, donor_images, donor_labels, gen, prob: float = 0.5, max_shift: float = 0.3):
    """The 2D control: each frame, with ``prob``, receives the pothole pixels of a random donor
    frame (one with potholes), in the same rows, shifted sideways by up to ``max_shift`` of the
    width (pixels shifted past the edge are dropped). Returns new uint8 tensors."""
    torch = _torch()
    dev = images.device
    b, h, w = labels.shape
    rnd = lambda *s: torch.rand(*s, generator=gen, device=dev)  # noqa: E731
    donor = (rnd(b) * donor_labels.shape[0]).long().clamp_(max=donor_labels.shape[0] - 1)
    shift = ((2 * rnd(b) - 1) * max_shift * w).round().long()
    src = torch.arange(w, device=dev)[None] - shift[:, None]                # (B, W) source column
    inside = (src >= 0) & (src < w)
    src = src.clamp(0, w - 1)
    d_lab = torch.gather(donor_labels[donor], 2, src[:, None, :].expand(b, h, w))
    d_img = torch.gather(donor_images[donor], 2, src[:, None, :, None].expand(b, h, w, 3))
    paste = (d_lab == POTHOLE) & inside[:, None, :] & (rnd(b) < prob)[:, None, None]
    return torch.where(paste[..., None], d_img, images), torch.where(paste, torch.full_like(labels, POTHOLE), labels)


def parse_style(text: str | None) -> float | None:
    """``fda:BETA`` -> BETA (the share of the shorter side whose low frequencies are swapped)."""
    if not text:
        return None
    kind, _, value = text.partition(":")
    try:
        beta = float(value or 0.01)
    except ValueError:
        beta = -1.0
    if kind != "fda" or not 0 < beta < 0.5:
        from roadtwin_core.errors import RoadtwinError

        raise RoadtwinError(f"--style: {text!r} is not fda:BETA with 0 < BETA < 0.5 (e.g. fda:0.01)")
    return beta


def fda(source, target, beta: float):
    """Fourier domain adaptation (Yang & Soatto, CVPR 2020): each source frame keeps its phase
    (layout, edges: what the labels describe) and takes the lowest-frequency amplitudes of a
    target frame (global colour, illumination, haze: the look of the real camera). uint8 (B,H,W,3)
    in and out; ``beta`` is the swapped square's side as a share of the shorter image side."""
    torch = _torch()
    s = source.permute(0, 3, 1, 2).float()
    t = target.permute(0, 3, 1, 2).float()
    h, w = s.shape[-2:]
    b = max(1, int(min(h, w) * beta))
    fs, ft = torch.fft.rfft2(s), torch.fft.rfft2(t)      # rfft: the columns' negative side is implied
    amp, phase, amp_t = fs.abs(), fs.angle(), ft.abs()
    amp[..., :b, :b] = amp_t[..., :b, :b]
    amp[..., h - b:, :b] = amp_t[..., h - b:, :b]
    out = torch.fft.irfft2(torch.polar(amp, phase), s=(h, w))
    return out.round_().clamp_(0, 255).to(torch.uint8).permute(0, 2, 3, 1)


def seg_loss(logits, target):
    """Cross-entropy + soft Dice over the foreground classes present, for thin cracks and small
    potholes."""
    torch = _torch()
    F = torch.nn.functional
    ce = F.cross_entropy(logits, target, ignore_index=IGNORE_INDEX)
    valid = (target != IGNORE_INDEX)
    prob = logits.float().softmax(1) * valid[:, None]
    onehot = F.one_hot(target.clamp(max=logits.shape[1] - 1), logits.shape[1]).permute(0, 3, 1, 2) * valid[:, None]
    inter = (prob * onehot).sum((0, 2, 3))[1:]
    denom = (prob + onehot).sum((0, 2, 3))[1:]
    present = (onehot.sum((0, 2, 3))[1:] > 0).float()
    dice = 1 - (2 * inter + 1) / (denom + 1)
    # the mean over present classes without a host sync (no boolean indexing, no .any())
    return ce + (dice * present).sum() / present.sum().clamp(min=1.0)


class Stream:
    """Seeded epochs of permutations over one source's frames, drawn ``k`` at a time."""

    def __init__(self, n: int, gen, device):
        self.n, self.gen, self.device = n, gen, device
        self.order = _torch().empty(0, dtype=_torch().long, device=device)

    def take(self, k: int):
        torch = _torch()
        while len(self.order) < k:
            self.order = torch.cat([self.order, torch.randperm(self.n, generator=self.gen, device=self.device)])
        idx, self.order = self.order[:k], self.order[k:]
        return idx


def _schedule(opt, steps: int, warmup: int):
    torch = _torch()
    warm = min(warmup, max(1, steps // 10))
    return torch.optim.lr_scheduler.LambdaLR(opt, lambda s: (s + 1) / warm if s < warm else
                                             0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * (s - warm) / max(1, steps - warm))))


def param_groups(model, cfg) -> list:
    """The optimizer's parameter groups: one rate for the whole network, or the ImageNet encoder's
    scaled by ``cfg.encoder_lr`` (``--encoder-lr``). Why: a lower rate keeps more of what the encoder
    learnt from real photos, which is what a model trained on synthetic frames alone can lean on."""
    scale = cfg.encoder_lr
    encoder = getattr(model, "encoder", None)
    if scale == 1 or encoder is None:
        return [{"params": list(model.parameters())}]
    inside = {id(p) for p in encoder.parameters()}
    return [{"params": [p for p in model.parameters() if id(p) in inside], "lr": cfg.lr * scale},
            {"params": [p for p in model.parameters() if id(p) not in inside]}]


def train_phase(model, data: dict, phase: Phase, cfg, device, log=print) -> dict:
    """``phase.steps`` AdamW steps (fresh optimizer: linear warm-up, cosine decay to 1 %) with
    batches from ``data`` ({source: (images, labels) device tensors}); bf16 autocast on CUDA."""
    torch = _torch()
    if phase.steps <= 0:
        return {"name": phase.name, "steps": 0, "seconds": 0.0, "counts": phase.counts}
    opt = torch.optim.AdamW(param_groups(model, cfg), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = _schedule(opt, phase.steps, cfg.warmup)
    dev = next(iter(data.values()))[0].device
    gen = torch.Generator(device=dev).manual_seed(phase.seed)
    streams = {s: Stream(data[s][0].shape[0], gen, dev) for s, k in phase.counts.items() if k > 0}
    beta = parse_style(cfg.style) if "style" in data else None
    styles = Stream(data["style"].shape[0], gen, dev) if beta else None
    donors = None
    if phase.paste:
        labels = data["real"][1]
        has = (labels == POTHOLE).flatten(1).any(1).nonzero()[:, 0]
        donors = (data["real"][0][has], labels[has])
    cuda = torch.device(device).type == "cuda"
    # a batch is its real frames first (phase.counts' order), then the synthetic ones: domain BNs
    # (bench/_domain_bn.py) normalize each part with its own pair
    if list(phase.counts)[:1] != ["real"] and phase.counts.get("real", 0):
        raise ValueError(f"phase {phase.name}: real frames must come first in a batch ({list(phase.counts)})")
    set_real_count(model, phase.counts.get("real", 0))
    model.train()
    t0, losses = time.perf_counter(), []
    for step in range(phase.steps):
        parts_x, parts_y = [], []
        for s, stream in streams.items():
            idx = stream.take(phase.counts[s])
            xi, yi = data[s][0][idx], data[s][1][idx]
            if s == "real" and donors is not None:
                xi, yi = copy_paste(xi, yi, *donors, gen)
            if s == "synth" and styles is not None:
                xi = fda(xi, data["style"][styles.take(xi.shape[0])], beta)
            parts_x.append(xi)
            parts_y.append(yi)
        x, y = augment(torch.cat(parts_x), torch.cat(parts_y), gen, train=True)
        if cuda:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=cuda):
            loss = seg_loss(model(x), y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % 500 == 0 or step == phase.steps - 1:
            value = loss.item()
            losses.append((step, round(value, 4)))
            log(f"    {phase.name} step {step + 1}/{phase.steps} loss {value:.3f} ({time.perf_counter() - t0:.0f} s)")
    if cuda:
        torch.cuda.synchronize()
    set_real_count(model, None)
    return {"name": phase.name, "steps": phase.steps, "seconds": round(time.perf_counter() - t0, 2),
            "counts": phase.counts, "paste": phase.paste, "loss": losses}


def recalibrate_bn(model, images, device, batch: int = 16) -> int:
    """AdaBN (Li et al. 2016): every batch-norm layer's running mean and variance recomputed from
    ``images`` (uint8 (N,H,W,3) on the device, preprocessed as for evaluation), the weights kept.
    Why: a model trained on mixed real and synthetic batches normalizes real frames with
    statistics partly of synthetic ones. Each BN layer's statistics become the plain average over
    the batches (momentum None); everything else runs as in evaluation (no dropout or drop-connect).
    Returns the number of BN layers recomputed."""
    torch = _torch()
    norms = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    saved = [m.momentum for m in norms]
    cuda = torch.device(device).type == "cuda"
    model.eval()
    for m in norms:
        m.reset_running_stats()
        m.momentum = None
        m.train()
    try:
        with torch.no_grad(), torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=cuda):
            for s in range(0, images.shape[0], batch):
                x, _ = augment(images[s:s + batch], images[s:s + batch, ..., 0], None, train=False)
                if cuda:
                    x = x.contiguous(memory_format=torch.channels_last)
                model(x)
    finally:
        for m, momentum in zip(norms, saved):
            m.momentum = momentum
        model.train()
    return len(norms)


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
            p, t = (pred[:, None] == ks) & valid, (y[:, None] == ks) & valid
            inter.append((p & t).sum((2, 3)).cpu())
            union.append((p | t).sum((2, 3)).cpu())
            for j in range(pred.shape[0]):
                if s + j in keep:
                    kept[s + j] = pred[j].to(torch.uint8).cpu().numpy()
    model.train()
    return torch.cat(inter).numpy().astype(np.int64), torch.cat(union).numpy().astype(np.int64), kept
