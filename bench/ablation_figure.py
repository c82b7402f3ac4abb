#!/usr/bin/env python
"""Issue 22's ablation as a figure: zero-shot IoU on real val per synthetic set (each realism
item off in turn), from the run JSONs of ``bench/perception.py train --arms e``.

    .venv/bin/python bench/ablation_figure.py docs/realism/ablation/zeroshot_*.json -o docs/realism/ablation/ablation.png

IoU per class = sum of intersections / sum of unions over the evaluation frames (what
bench/perception.py reports). Prints the table it draws.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

CLASSES = ("pothole", "crack", "ego_lane")
COLUMNS = {"background": 0, "ego_lane": 1, "crack": 2, "pothole": 3}


def run_iou(path: Path) -> dict[str, float]:
    run = json.loads(path.read_text())
    inter, union = np.asarray(run["I"], float).sum(axis=0), np.asarray(run["U"], float).sum(axis=0)
    return {c: 100 * inter[COLUMNS[c]] / max(union[COLUMNS[c]], 1) for c in CLASSES}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="zeroshot_<variant>.json run files")
    ap.add_argument("-o", "--out", type=Path, required=True)
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [p.stem.removeprefix("zeroshot_") for p in args.runs]
    table = [run_iou(p) for p in args.runs]
    print("| synthetic set | " + " | ".join(CLASSES) + " |\n|---|" + "---|" * len(CLASSES))
    for n, t in zip(names, table):
        print(f"| {n} | " + " | ".join(f"{t[c]:.1f}" for c in CLASSES) + " |")
    fig, axes = plt.subplots(1, len(CLASSES), figsize=(12, 3.6), sharey=False)
    for ax, c in zip(axes, CLASSES):
        vals = [t[c] for t in table]
        ax.barh(names, vals, color=["#555" if n.startswith("full") else "#4a8" for n in names])
        for y, v in enumerate(vals):
            ax.text(v, y, f" {v:.1f}", va="center", fontsize=8)
        ax.set_title(f"{c} IoU (real val)")
        ax.set_xlim(0, max(vals) * 1.25)
    fig.suptitle("zero-shot on real val, one seed, 2,250 steps: each realism item off in turn")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
