"""Class-balanced pseudo-labels (CBST, Zou et al., ECCV 2018) for the zero-shot arm of
bench/perception.py (``--pseudo-labels KEEP``): unsupervised domain adaptation from the real
train *images*, never their labels.

Why: a model trained on synthetic frames alone is most wrong where the real frames look unlike
them, yet it is right on many real pixels, and confidently so. Labelling the real train images
with its most confident predictions and training on them next to the synthetic frames adapts
it to the real look. Per class, not overall: a single confidence threshold keeps almost only
road and background (the model is surest there) and drops the rare classes the benchmark is
about; CBST keeps, for each class, the ``keep`` share of the pixels predicted as that class
with the highest confidence. The rest is ignored by the loss.
"""
from __future__ import annotations

import numpy as np

BINS = 4096     # confidence histogram per class: thresholds to 1/4096, deterministic on any device


def _torch():
    import torch

    return torch


def class_thresholds(conf, pred, num_classes: int, keep: float):
    """Per class c, the confidence above which the ``keep`` share of the pixels predicted c lies
    (from a histogram of ``BINS`` bins; 1.0 where no pixel is predicted c)."""
    torch = _torch()
    device = conf[0].device
    out = torch.ones(num_classes, dtype=torch.float32, device=device)
    for c in range(num_classes):
        hist = torch.zeros(BINS, dtype=torch.float64, device=device)
        for part_conf, part_pred in zip(conf, pred):
            sel = part_conf[part_pred == c].float()
            if sel.numel():
                hist += torch.histc(sel, bins=BINS, min=0.0, max=1.0).double()
        total = hist.sum()
        if total <= 0:
            continue
        above = hist.flip(0).cumsum(0).flip(0)           # pixels at or above each bin's lower edge
        ok = (above >= keep * total).nonzero()
        out[c] = float(ok.max()) / BINS if len(ok) else 0.0
    return out


def pseudo_labels(model, images, device, batch: int, keep: float, ignore_index: int):
    """(N, H, W) uint8 labels of ``images`` (uint8 (N, H, W, 3) on the device) by ``model`` in
    evaluation: each pixel its predicted class where its confidence reaches that class's
    threshold (:func:`class_thresholds`), else ``ignore_index``. Returns (labels, info)."""
    from _perception_train import augment

    torch = _torch()
    cuda = torch.device(device).type == "cuda"
    was_training = model.training
    model.eval()
    confs, preds = [], []
    with torch.no_grad(), torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=cuda):
        for s in range(0, images.shape[0], batch):
            x, _ = augment(images[s:s + batch], images[s:s + batch, ..., 0], None, train=False)
            if cuda:
                x = x.contiguous(memory_format=torch.channels_last)
            prob = model(x).float().softmax(1)
            conf, pred = prob.max(1)
            confs.append(conf.half())
            preds.append(pred.to(torch.uint8))
    model.train(was_training)
    num_classes = int(prob.shape[1])
    thresholds = class_thresholds(confs, preds, num_classes, keep)
    labels = torch.cat([torch.where(c.float() >= thresholds[p.long()], p, torch.full_like(p, ignore_index))
                        for c, p in zip(confs, preds)])
    kept = [(labels == c).sum().item() for c in range(num_classes)]
    predicted = [sum((p == c).sum().item() for p in preds) for c in range(num_classes)]
    info = {"keep": keep, "frames": int(images.shape[0]), "thresholds": [round(float(t), 4) for t in thresholds],
            "kept_pixels": kept, "predicted_pixels": predicted,
            "kept_share": float(np.sum(kept) / max(1, np.sum(predicted)))}
    return labels, info
