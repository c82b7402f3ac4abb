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

``--by-road`` (road_defects_br names ``<id>_<state>_<road>_...``): per road of each folder, its
frames, the frames with a pothole, pothole pixels per frame, the road's share of the folder's
pothole pixels, and the elongation (major / minor axis of the second moments: a disc 1, a w x h
bar w/h) and area of the pothole component its median pothole pixel belongs to. Why: zero-shot scored 2-4 pothole IoU on the
train frames and 11-13 on val; 95 % of train's pothole pixels are one road's (RS_290), labelled as
long wheel-path strips, where val's are compact holes. ``--figure OUT.jpg``: each road's frame
with the most pothole pixels beside its labels (pothole red, crack green).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import sys

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))        # bench/_perception_data: road names
from _perception_data import road_of  # noqa: E402

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


def elongation(mask: np.ndarray) -> float:
    """Major over minor axis of a component's second moments (sqrt of the covariance's eigenvalue
    ratio): 1 for a disc or a square, w/h for a w x h bar."""
    ys, xs = np.nonzero(mask)
    lo, hi = np.linalg.eigvalsh(np.cov(np.stack([xs, ys]).astype(float)) + 1e-9 * np.eye(2))
    return float(np.sqrt(hi / max(lo, 1e-9)))


def pixel_median(values: list[float], areas: list[int]) -> float | None:
    """The value of the component the median pothole pixel belongs to (components weighted by
    their pixels): what most of the labelled area looks like, where a plain median counts specks."""
    if not values:
        return None
    order = np.argsort(values)
    cum = np.cumsum(np.asarray(areas, float)[order])
    return float(np.asarray(values, float)[order][np.searchsorted(cum, cum[-1] / 2)])


def road_stats(folder: Path, every: int = 1) -> dict:
    """Per road of a label folder: frames, frames with >= MIN_PIXELS pothole pixels, pothole pixels
    per frame, share of the folder's pothole pixels, the pixel-weighted median elongation and area
    of its pothole components (8-connected, >= MIN_PIXELS), and the frame with the most pothole pixels."""
    roads: dict[str, dict] = {}
    for f in sorted(folder.glob("*.png"))[::every]:
        lab = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if lab is None or lab.ndim != 2:
            raise SystemExit(f"error: {f}: not a single-channel label PNG")
        r = roads.setdefault(road_of(f.stem), {"frames": 0, "pothole_frames": 0, "pothole_px": 0, "elong": [], "area": [],
                                               "top": (0, None)})
        pothole = lab == 3
        n = int(pothole.sum())
        r["frames"] += 1
        r["pothole_px"] += n
        r["pothole_frames"] += n >= MIN_PIXELS
        r["top"] = max(r["top"], (n, f.stem), key=lambda t: t[0])
        count, comp, stats, _ = cv2.connectedComponentsWithStats(pothole.astype(np.uint8), connectivity=8)
        for k in range(1, count):
            if stats[k, cv2.CC_STAT_AREA] >= MIN_PIXELS:
                r["elong"].append(elongation(comp == k))
                r["area"].append(int(stats[k, cv2.CC_STAT_AREA]))
    total = sum(r["pothole_px"] for r in roads.values()) or 1
    return {road: {"frames": r["frames"], "pothole_frames": int(r["pothole_frames"]),
                   "pothole_px_per_frame": r["pothole_px"] / r["frames"], "pothole_share": r["pothole_px"] / total,
                   "components": len(r["elong"]),
                   "median_elongation": pixel_median(r["elong"], r["area"]),
                   "median_area_px": pixel_median(r["area"], r["area"]), "top_frame": r["top"][1]}
            for road, r in sorted(roads.items(), key=lambda kv: -kv[1]["pothole_px"])}


def road_figure(stats: dict[Path, dict], out: Path) -> Path:
    """Each road's frame with the most pothole pixels (images/ beside labels/), its labels laid over
    it (pothole red, crack green), one row per road, the road's name written on it. ``stats``: per
    label folder, its :func:`road_stats`."""
    rows = []
    for folder, roads in stats.items():
        for road, r in roads.items():
            if r["top_frame"] is None:
                continue
            stem = r["top_frame"]
            lab = cv2.imread(str(folder / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
            img = next((cv2.imread(str(p)) for p in (folder.parent / "images").glob(f"{stem}.*")), None)
            if img is None:
                continue
            img = cv2.resize(img, lab.shape[::-1], interpolation=cv2.INTER_AREA)
            over = img.astype(float)
            for c, bgr in ((3, (0, 0, 255)), (2, (0, 255, 0))):
                over[lab == c] = 0.4 * over[lab == c] + 0.6 * np.array(bgr)
            row = np.concatenate([img, over.astype(np.uint8)], 1)
            cv2.putText(row, f"{folder.parent.name} {road}: {100 * r['pothole_share']:.0f} % of the pothole pixels, "
                        f"elongation {r['median_elongation'] or 0:.1f}", (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                        (255, 255, 255), 2, cv2.LINE_AA)
            rows.append(row)
    if not rows:
        raise SystemExit("error: --figure: no frame with its image beside the labels (FOLDER/../images)")
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(rows, 0))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--every", type=int, default=1, help="every N-th frame (sorted names)")
    ap.add_argument("--by-road", action="store_true", help="pothole pixels, shares and component shapes per road")
    ap.add_argument("--figure", type=Path, help="each road's frame with the most pothole pixels, labels over it (.jpg or .png)")
    args = ap.parse_args()
    roads = {folder: road_stats(folder, args.every) for folder in args.folders} if args.figure or args.by_road else {}
    if args.figure:
        print(f"wrote {road_figure(roads, args.figure)}")
    if args.by_road:
        print("| labels | road | frames | with pothole | pothole px / frame | share of the pothole pixels | "
              "components | elongation (pixel median) | component area px (pixel median) |")
        print("|---|---|---|---|---|---|---|---|---|")
        for folder, per_road in roads.items():
            for road, r in per_road.items():
                fmt = lambda v, spec: "-" if v is None else format(v, spec)
                print(f"| {folder} | {road} | {r['frames']} | {r['pothole_frames']} | {r['pothole_px_per_frame']:.0f} | "
                      f"{100 * r['pothole_share']:.1f} % | {r['components']} | {fmt(r['median_elongation'], '.2f')} | "
                      f"{fmt(r['median_area_px'], '.0f')} |")
        return
    print("| labels | frames | crack % | pothole % | frames with crack / pothole | crack 2A/P px | pothole 2A/P px |")
    print("|---|---|---|---|---|---|---|")
    for folder in args.folders:
        s = folder_stats(folder, args.every)
        fmt = lambda v: "-" if v is None else f"{v:.2f}"
        print(f"| {folder} | {s['frames']} | {s['share_pct'][2]:.3f} | {s['share_pct'][3]:.3f} | "
              f"{s['crack_frames']} / {s['pothole_frames']} | {fmt(s['crack_2A_P_px'])} | {fmt(s['pothole_2A_P_px'])} |")


if __name__ == "__main__":
    main()
