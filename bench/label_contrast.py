#!/usr/bin/env python
"""How visible are the labelled defects? Weber contrast of each labelled instance against the road
just outside it, per class (issue 22: photo-made crack strokes rendered nearly invisible where
they are labelled crack, and a label without a visible defect teaches a network nothing).

    .venv/bin/python bench/label_contrast.py ../shared/data/road_defects_br/train OUT/strokes_render [--every 2]

A folder is a dataset split (``images/`` + ``labels/``, same stems) or a render (``meta.json``:
its frames' ``rgb`` and ``semantic`` files, class ids by name). Per instance (an 8-connected
component of a class, >= ``MIN_PIXELS`` px): ``C = (L_ring - L_in) / L_ring``, ``L`` the mean
luma (Rec.709 weights on the 8-bit sRGB values: what a network sees) over the instance's pixels
(``L_in``) and over its ring (``L_ring``: pixels within ``ring_px`` of it, chessboard, labelled
neither crack nor pothole). Dark defects give C > 0; C = 0 is a label with nothing to see.
``C_core`` is the same with ``L_in`` over the darkest third of the instance's pixels only: how
dark the defect itself is, apart from the light margin a label has around it (real crack labels
are ~2 px wide strokes; the renderer's class map grows a rendered crack by 1 px, ``dilate_px``).
Prints per folder and class the instances, the median C and its quartiles, the share with
C >= 0.1, and the median C_core. Never run it on val. Not a test.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

CLASSES = {"crack": 2, "pothole": 3}          # road_defects_br's ids (render folders: read from meta.json)
MIN_PIXELS = 10
CORE_SHARE = 1 / 3
REC709 = np.array([0.2126, 0.7152, 0.0722])


def luma(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luma of 8-bit RGB (H, W, 3), in [0, 1]."""
    return (rgb.astype(np.float64) / 255.0) @ REC709


def instance_contrasts(rgb: np.ndarray, label: np.ndarray, class_id: int, defect_ids, ring_px: int = 2,
                       min_pixels: int = MIN_PIXELS) -> list[tuple[float, float]]:
    """(C, C_core) of each instance of ``class_id`` in one frame (``rgb`` RGB uint8, ``label``
    class ids): Weber contrasts (ring - inside) / ring over all its pixels and over its darkest
    third; instances whose ring is empty are left out."""
    lum = luma(rgb)
    defect = np.isin(label, list(defect_ids))
    n, comp, stats, _ = cv2.connectedComponentsWithStats((label == class_id).astype(np.uint8), connectivity=8)
    kernel = np.ones((2 * ring_px + 1, 2 * ring_px + 1), np.uint8)
    out = []
    for c in range(1, n):
        if stats[c, cv2.CC_STAT_AREA] < min_pixels:
            continue
        x0, y0, w, h = (int(v) for v in stats[c, :4])
        ys = slice(max(y0 - ring_px, 0), y0 + h + ring_px)
        xs = slice(max(x0 - ring_px, 0), x0 + w + ring_px)
        inst = comp[ys, xs] == c
        ring = cv2.dilate(inst.astype(np.uint8), kernel).astype(bool) & ~defect[ys, xs]
        if not ring.any():
            continue
        l_ring = max(float(lum[ys, xs][ring].mean()), 1e-6)
        inside = np.sort(lum[ys, xs][inst])
        core = inside[:int(np.ceil(CORE_SHARE * len(inside)))]
        out.append(((l_ring - float(inside.mean())) / l_ring, (l_ring - float(core.mean())) / l_ring))
    return out


def frames(folder: Path, every: int) -> tuple[dict[str, int], list[tuple[Path, Path]]]:
    """({class name: id}, [(rgb, label)]) of a render (meta.json) or a split (images/, labels/)."""
    if (folder / "meta.json").exists():
        meta = json.loads((folder / "meta.json").read_text())
        ids = {c["name"]: c["id"] for c in meta["classes"] if c["name"] in CLASSES}
        pairs = [(folder / f["files"]["rgb"], folder / f["files"]["semantic"]) for f in meta["frames"]]
    else:
        ids = dict(CLASSES)
        labels = {p.stem: p for p in (folder / "labels").glob("*.png")}
        pairs = [(p, labels[p.stem]) for p in sorted((folder / "images").iterdir()) if p.stem in labels]
    if not pairs:
        raise SystemExit(f"error: {folder}: no frames (neither meta.json nor images/ + labels/)")
    return ids, pairs[::every]


def folder_contrasts(folder: Path, every: int = 1, ring_px: int = 2) -> dict[str, list[tuple[float, float]]]:
    ids, pairs = frames(folder, every)
    out: dict[str, list[tuple[float, float]]] = {name: [] for name in ids}
    for rgb_path, label_path in pairs:
        bgr = cv2.imread(str(rgb_path), cv2.IMREAD_COLOR)
        label = cv2.imread(str(label_path), cv2.IMREAD_UNCHANGED)
        if bgr is None or label is None or label.ndim != 2 or label.shape != bgr.shape[:2]:
            raise SystemExit(f"error: {label_path}: not a single-channel label of its image's size")
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        for name, cid in ids.items():
            out[name] += instance_contrasts(rgb, label, cid, ids.values(), ring_px)
    return out


def summary(pairs: list[tuple[float, float]]) -> str:
    """``n | median C [q25, q75] | share C >= 0.1 | median C_core`` of (C, C_core) pairs."""
    if not pairs:
        return "0 | - | - | -"
    c, core = np.asarray(pairs).T
    q25, q50, q75 = np.percentile(c, [25, 50, 75])
    return f"{len(c)} | {q50:.3f} [{q25:.3f}, {q75:.3f}] | {100 * np.mean(c >= 0.1):.0f} % | {np.median(core):.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--every", type=int, default=1, help="every N-th frame")
    ap.add_argument("--ring-px", type=int, default=2, help="ring width outside each instance (px)")
    args = ap.parse_args()
    print("| frames | class | instances | Weber contrast C median [q25, q75] | C >= 0.1 | C_core median |\n"
          "|---|---|---|---|---|---|")
    for folder in args.folders:
        for name, values in folder_contrasts(folder, args.every, args.ring_px).items():
            print(f"| {folder} | {name} | {summary(values)} |")


if __name__ == "__main__":
    main()
