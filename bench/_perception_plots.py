"""Figures of bench/perception.py's report: gains.png (each arm's gain over real-only, per
fraction, with its paired bootstrap interval) and grid.jpg (predictions of every arm on a few
val frames, one seed and fraction)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from roadtwin_core.datasets import IGNORE_INDEX

PALETTE = np.array([[0, 0, 0], [40, 110, 255], [255, 210, 0], [255, 30, 30]], dtype=np.uint8)
ARM_COLOURS = {"pretrain": "#1f77b4", "mixed": "#2ca02c", "paste": "#ff7f0e", "zeroshot": "#9467bd"}
ARM_LABELS = {"pretrain": "(b) synthetic pre-train", "mixed": "(c) mixed batches", "paste": "(d) copy-paste",
              "zeroshot": "(e) zero-shot"}


def seed_text(gains: dict, over: str) -> str:
    """The seeds behind the bars over one baseline, e.g. "seeds 0, 1, 2" or "seed 0" (a bar over
    fewer seeds than the figure's others must say so)."""
    seeds = sorted({s for g in gains.values() if g["over"] == over for s in g["seeds"]})
    return ("seed " if len(seeds) == 1 else "seeds ") + ", ".join(map(str, seeds))


def gains_plot(summary: dict, path: Path, metrics=("pothole", "mIoU")) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    gains = {k: g for k, g in summary["gains"].items() if not g.get("moonshot")}
    if not gains:
        return None
    overs = sorted({g["over"] for g in gains.values()}, key=lambda o: -float(o.split("@")[1].rstrip("%")))
    arms = [a for a in ARM_COLOURS if any(g["arm"] == a for g in gains.values())]
    fig, axes = plt.subplots(1, len(metrics), figsize=(5.2 * len(metrics), 3.8), squeeze=False)
    width = 0.8 / len(arms)
    for ax, m in zip(axes[0], metrics):
        for j, arm in enumerate(arms):
            xs, ys, err = [], [], [[], []]
            for k, over in enumerate(overs):
                g = next((g for g in gains.values() if g["arm"] == arm and g["over"] == over), None)
                if g is None or not np.isfinite(g[m]["gain"]):
                    continue
                xs.append(k + (j - (len(arms) - 1) / 2) * width)
                ys.append(100 * g[m]["gain"])
                err[0].append(max(0.0, 100 * (g[m]["gain"] - g[m]["lo"])))
                err[1].append(max(0.0, 100 * (g[m]["hi"] - g[m]["gain"])))
            ax.bar(xs, ys, width, yerr=err, capsize=3, color=ARM_COLOURS[arm], label=ARM_LABELS[arm])
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(range(len(overs)), [f"{o.split('@')[1]} real\n{seed_text(gains, o)}" for o in overs])
        ax.set_ylabel(f"{m.replace('_', ' ')} gain over (a) real only (IoU points)")
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"gain over real-only, equal steps ({summary['steps_per_run']}), {summary['eval']['frames']} "
                 f"val frames, each bar's seeds pooled (under it), 95 % paired bootstrap", fontsize=9)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def prediction_grid(runs: list[dict], eval_grid: Path, path: Path, fraction: float | None = None) -> Path | None:
    """Image, ground truth and each arm's prediction on the grid frames, the lowest seed, at
    ``fraction`` (default: the smallest fraction run)."""
    from PIL import Image, ImageDraw

    fracs = sorted({r["fraction"] for r in runs if r["fraction"] is not None})
    if not fracs or not eval_grid.exists():
        return None
    frac = fraction if fraction in fracs else fracs[0]
    seed = min(r["seed"] for r in runs)
    chosen = [r for r in runs if r["seed"] == seed and (r["fraction"] == frac or r["arm"] == "zeroshot")]
    chosen.sort(key=lambda r: r["letter"])
    with np.load(eval_grid) as z:
        frames, images, labels = list(z["frames"]), z["images"], z["labels"]
    cols = [(f"val image (seed {seed}, {100 * frac:g} % real)", None), ("ground truth", labels)]
    for r in chosen:
        with np.load(Path(r["_file"]).with_suffix(".npz")) as z:
            pos = {int(f): k for k, f in enumerate(z["frames"])}
            preds = z["preds"]
        if all(f in pos for f in frames):
            cols.append((f"({r['letter']}) {r['name']}", np.stack([preds[pos[f]] for f in frames])))
    h, w = labels.shape[1:]
    tw, th = 256, max(1, round(h * 256 / w))
    sheet = Image.new("RGB", (tw * len(cols), 16 + th * len(frames)), (20, 20, 20))
    draw = ImageDraw.Draw(sheet)
    for j, (title, labs) in enumerate(cols):
        draw.text((j * tw + 4, 2), title, fill=(230, 230, 230))
        for i in range(len(frames)):
            tile = images[i]
            if labs is not None:
                col = PALETTE[np.minimum(labs[i], 3)]
                col[labs[i] == IGNORE_INDEX] = 128
                tile = (0.45 * images[i] + 0.55 * col).astype(np.uint8)
            sheet.paste(Image.fromarray(tile).resize((tw, th), Image.NEAREST), (j * tw, 16 + i * th))
    sheet.save(path, quality=90)
    return path


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


def compare_plot(cmp: dict, path: Path, metrics=("pothole", "crack", "ego_lane", "mIoU")) -> Path:
    """``compare``'s gains of B over A as bars with their 95 % paired-bootstrap intervals, one group
    per run name (its seeds under it), one bar per metric."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from _perception_report import compare_where, differ_text

    names = list(cmp["rows"])
    fig, ax = plt.subplots(figsize=(max(6.4, 1.6 + 1.9 * len(names) * len(metrics) / 4), 3.8))
    width = 0.8 / len(metrics)
    colours = plt.get_cmap("tab10").colors
    for j, m in enumerate(metrics):
        g = [cmp["rows"][n]["gain"][m] for n in names]
        ys = [100 * x["gain"] for x in g]
        err = [[max(0.0, 100 * (x["gain"] - x["lo"])) for x in g], [max(0.0, 100 * (x["hi"] - x["gain"])) for x in g]]
        ax.bar([k + (j - (len(metrics) - 1) / 2) * width for k in range(len(names))], ys, width, yerr=err, capsize=3,
               color=colours[j % len(colours)], label=m.replace("_", " "))
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(range(len(names)), [f"{n}\nseeds {', '.join(map(str, cmp['rows'][n]['seeds']))}" for n in names])
    ax.set_ylabel("gain of B over A (IoU points)")
    ax.grid(axis="y", alpha=0.3)
    where = compare_where(cmp).replace("`", "")
    ax.set_title(f"B over A ({differ_text(cmp)})\non {where}; seeds pooled, 95 % paired bootstrap",
                 fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
