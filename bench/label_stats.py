#!/usr/bin/env python
"""Pixel shares and stroke widths of label folders: what a synthetic set's labels look like
beside the real ones (issue 22's ablation: photo crack areas were labelled twice as wide as
real crack strokes).

    .venv/bin/python bench/label_stats.py ../shared/data/road_defects_br/train/labels OUT/synthetic/labels [--every 10]

Per folder: each class's share of all pixels, the frames holding >= 20 pixels of crack /
pothole, and the median over those frames of 2A/P (area x 2 / boundary pixels, the width in
px of a stroke; a filled blob of radius r gives ~r). Class ids are road_defects_br's
(0 background, 1 ego lane, 2 crack, 3 pothole). Not a test. ``--every N`` on a rendered set: pick N
coprime to the aimed share's period (``--views defects:0.8`` aims 4 frames in every 5, spread evenly
over the indices, so ``--every 5`` reads only the frames aimed at no defect).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

CLASSES = ("background", "ego_lane", "crack", "pothole")
MIN_PIXELS = 20


def stroke_width(mask: np.ndarray) -> float:
    """2A/P of a mask: P counts mask pixels with a 4-neighbour outside it (image edge = outside)."""
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    area = int(mask.sum())
    return 2.0 * area / max(area - int(inner.sum()), 1)


def folder_stats(folder: Path, every: int) -> dict:
    files = sorted(folder.glob("*.png"))[::every]
    if not files:
        raise SystemExit(f"error: {folder}: no label PNGs")
    counts = np.zeros(len(CLASSES))
    total = 0
    widths = {2: [], 3: []}
    for f in files:
        lab = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if lab is None or lab.ndim != 2:
            raise SystemExit(f"error: {f}: not a single-channel label PNG")
        counts += np.bincount(lab.ravel(), minlength=256)[:len(CLASSES)]
        total += lab.size
        for c in widths:
            m = lab == c
            if m.sum() >= MIN_PIXELS:
                widths[c].append(stroke_width(m))
    return {"frames": len(files), "share_pct": (100 * counts / total).round(3).tolist(),
            "crack_frames": len(widths[2]), "pothole_frames": len(widths[3]),
            "crack_2A_P_px": float(np.median(widths[2])) if widths[2] else None,
            "pothole_2A_P_px": float(np.median(widths[3])) if widths[3] else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--every", type=int, default=1, help="every N-th frame (sorted names)")
    args = ap.parse_args()
    print("| labels | frames | crack % | pothole % | frames with crack / pothole | crack 2A/P px | pothole 2A/P px |")
    print("|---|---|---|---|---|---|---|")
    for folder in args.folders:
        s = folder_stats(folder, args.every)
        fmt = lambda v: "-" if v is None else f"{v:.2f}"
        print(f"| {folder} | {s['frames']} | {s['share_pct'][2]:.3f} | {s['share_pct'][3]:.3f} | "
              f"{s['crack_frames']} / {s['pothole_frames']} | {fmt(s['crack_2A_P_px'])} | {fmt(s['pothole_2A_P_px'])} |")


if __name__ == "__main__":
    main()
