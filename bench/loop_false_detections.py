"""What the loop's false detections lie on (issue 20, item 5; docs/stereo_detector.md).

For every detection of ``reconstruct defects`` that lies mostly off every true defect (the
loop's "false" count, bench/_loop_stereo.py), on the disparity maps bench/loop.py kept
(``--reuse``), the drive's truth names a cause, the first that applies in this order:

- ``border``: within BORDER_PX of the image border or of the crop's top row (the ROI edge);
- ``defect_neighbour``: within NEAR_DEFECT_PX of a true defect instance (any type);
- ``occlusion_edge``: within EDGE_PX of a non-paved pixel (vehicle, prop, verge, sidewalk: the
  road mask's edge, named by the class met) or of a true-depth step > DEPTH_STEP (relative);
- ``lane_marking``: on or within MARK_PX of lane-marking pixels;
- ``shadow_edge``: a luminance step across the region (left image, 5 px blur) > SHADOW_STEP
  x the road's median grey level (shadows are not labelled; a strong edge that is not a
  marking is one on these renders);
- ``low_texture``: the region's RMS row gradient (the LK window's) below the road's 25th
  percentile;
- ``other``: none of these (textured, flat, open road).

    PYTHONPATH=.:plugins .venv/bin/python bench/loop_false_detections.py [--out out/loop_tune]
        [--cases tune_highway_D_seed23,tune_town_seed3] [--tag lk6x2_reject1.3x2] [--k-region K]
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "plugins"), str(ROOT / "bench")]
from _loop_data import PAVED, Bag  # noqa: E402
from _loop_stereo import ROI_M, _crop, add_kept_map_args, road_mask, road_rows  # noqa: E402

CAUSES = ("border", "defect_neighbour", "occlusion_edge", "lane_marking", "shadow_edge", "low_texture", "other")
BORDER_PX, NEAR_DEFECT_PX, EDGE_PX, MARK_PX = 3, 10, 6, 3
DEPTH_STEP, SHADOW_STEP = 0.05, 0.25


def _ring(mask: np.ndarray, px: int) -> np.ndarray:
    import cv2

    return cv2.dilate(mask.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)) > 0


def _gray(img: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32) if img.ndim == 3 else img.astype(np.float32)


def classify(fr: dict, labels: np.ndarray, classes: list[str]) -> list[tuple[str, str]]:
    """(cause, detail) per false detection of one frame."""
    import cv2

    sem, gt, depth = fr["semantic"], fr["instance"], fr["depth"].astype(np.float64)
    h, w = labels.shape
    border = np.zeros((h, w), bool)
    border[:BORDER_PX, :] = border[-BORDER_PX:, :] = border[:, :BORDER_PX] = border[:, -BORDER_PX:] = True
    paved = np.isin(sem, [i for i, n in enumerate(classes) if n in PAVED])
    marking = sem == classes.index("lane_marking")
    step = np.zeros((h, w), bool)
    z = np.where(depth > 0, depth, np.nan)
    with np.errstate(invalid="ignore"):
        step[:, 1:] |= np.abs(np.diff(z, axis=1)) > DEPTH_STEP * z[:, 1:]
        step[1:, :] |= np.abs(np.diff(z, axis=0)) > DEPTH_STEP * z[1:, :]
    gray = _gray(fr["left"])
    blur = cv2.GaussianBlur(gray, (0, 0), 5)
    gx = np.gradient(gray, axis=1)
    tex = np.sqrt(cv2.GaussianBlur(gx * gx, (0, 0), sigmaX=6, sigmaY=2))
    road = paved & (gt == 0) & ~marking
    road_grey, tex_q25 = np.median(gray[road]), np.percentile(tex[road], 25)
    out = []
    for i in range(1, int(labels.max()) + 1):
        reg = labels == i
        if not reg.any() or (gt[reg] > 0).mean() >= 0.5:
            continue
        if (reg & border).any():
            vs, us = np.nonzero(reg)
            side = "top (ROI row)" if vs.min() < BORDER_PX else "bottom" if vs.max() >= h - BORDER_PX else \
                "left" if us.min() < BORDER_PX else "right"
            out.append(("border", side))
        elif (_ring(reg, NEAR_DEFECT_PX) & (gt > 0)).any():
            out.append(("defect_neighbour", ""))
        elif (_ring(reg, EDGE_PX) & (~paved | step)).any():
            near = _ring(reg, EDGE_PX) & ~paved
            names = Counter(classes[c] if c < len(classes) else str(c) for c in sem[near]) if near.any() else {}
            out.append(("occlusion_edge", max(names, key=names.get) if names else "depth step"))
        elif (_ring(reg, MARK_PX) & marking).any():
            out.append(("lane_marking", ""))
        elif np.ptp(blur[_ring(reg, EDGE_PX)]) > SHADOW_STEP * road_grey:
            out.append(("shadow_edge", ""))
        elif np.sqrt(np.mean(tex[reg] ** 2)) < tex_q25:
            out.append(("low_texture", ""))
        else:
            out.append(("other", ""))
    return out


def main() -> None:
    import json

    from roadtwin_stereo import StereoDefects

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_kept_map_args(ap, ROOT, "tune_highway_D_seed23,tune_town_seed3", border_px=0)
    ap.add_argument("--exclude-marking", action="store_true", help="road mask without lane-marking pixels")
    args = ap.parse_args()
    rec = StereoDefects()
    table = {}
    for case in args.cases.split(","):
        cache = args.out / case / f"disparity_1280x720_{args.tag}.npz"
        if not cache.exists():
            print(f"{cache}: no kept disparity maps (run bench/loop.py --reuse first)", file=sys.stderr)
            sys.exit(2)
        from _loop_data import load_truth

        summary = json.loads((args.out / case / "drive" / "summary.json").read_text())
        classes, truth = summary["classes"], load_truth(args.out / case / "town" / "town.usda")
        maps, causes, details = np.load(cache), Counter(), Counter()
        for k, fr in enumerate(Bag(args.out / case / "drive").stereo_frames()):
            fr = _crop(fr, road_rows(fr, truth, ROI_M))
            mask = road_mask(fr["semantic"], classes)
            if args.exclude_marking:
                mask = mask & ~_ring(fr["semantic"] == classes.index("lane_marking"), 3)
            res = rec.run({"disparity": maps[f"f{k:03d}"].astype(np.float64), "K": fr["K"],
                           "baseline": fr["baseline"], "road_mask": mask, "source": f"frame_{k:03d}"},
                          rec.Params(texture=False, border_px=args.border_px, k_region=args.k_region,
                                     road_refit_k=args.refit_k))
            for cause, detail in classify(fr, res.labels, classes):
                causes[cause] += 1
                details[f"{cause}: {detail}"] += bool(detail)
            print(f"  {case} frame {k:03d}", file=sys.stderr, flush=True)
        table[case] = (causes, details)
    print(f"false detections by cause ({args.tag}, border_px {args.border_px}{', marking excluded' if args.exclude_marking else ''}):")
    print(f"  {'cause':18s}" + "".join(f"{c:>24s}" for c in table))
    for cause in CAUSES:
        print(f"  {cause:18s}" + "".join(f"{t[0][cause]:24d}" for t in table.values()))
    print(f"  {'total':18s}" + "".join(f"{sum(t[0].values()):24d}" for t in table.values()))
    for case, (_, det) in table.items():
        print(f"  {case} details: " + ", ".join(f"{k} {v}" for k, v in det.items() if v))


if __name__ == "__main__":
    main()
