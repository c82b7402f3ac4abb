"""Leave-one-out cross-validation of the transformed-disparity pothole detector (issues 14 and 20).

The detector (plugins/roadtwin_stereo/segment.py) has two numbers chosen by looking at labels:
``k_seed`` (how deep, in road-noise sigmas, a region must reach to be a pothole) and
``depth_frac`` (where a pothole ends, as a fraction of its own depth). For each of the N frames,
they are chosen on the other N-1 frames (grid search, best mean F1, ties to the first in grid
order) and the held-out frame is scored with them. Everything else is derived from the frame.
This is done for both road models (``--param``-free: SegmentParams.road_model): the local robust
model (default since issue 20: sigma = small-scale noise after a tiled robust correction,
plugins/roadtwin_stereo/road_model.py) and the global quadratic (issue 14). Printed: per-frame
held-out precision / recall / F1, the chosen parameters per fold, mean F1 and pixel-pooled F1,
and the same with the shipped defaults. The detector's physical floor (StereoDefectsParams
floor_depth_m / floor_area_m2, metres) does not apply here: these maps are transformed and
normalised, without K or units.

    PYTHONPATH=.:plugins .venv/bin/python bench/stereo_cv.py [DATA_DIR]

DATA_DIR holds disp_tg/NN.png and label/NN.png (default ../shared/data/stereo_pothole, else
tests/data/stereo_pothole). About 3 minutes on one core for 13 frames.
"""
from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
from roadtwin_stereo.segment import (SegmentParams, load_disparity, load_label,
                                     road_residual, segment_residual)

GRID = {"k_seed": [5.0, 7.5, 10.0, 15.0, 20.0, 30.0], "depth_frac": [0.0, 0.05, 0.1, 0.15, 0.2, 0.3]}
MODELS = {"local": [0.0625, 0.125], "quadratic": [0.125]}  # road model: tile_frac values tried


def _data_dir() -> Path:
    if len(sys.argv) > 1:
        return Path(sys.argv[1])
    shared = ROOT.parents[1] / "shared" / "data" / "stereo_pothole"
    for cand in (Path("/work/shared/data/stereo_pothole"), shared, ROOT / "tests" / "data" / "stereo_pothole"):
        if (cand / "disp_tg").is_dir():
            return cand
    raise SystemExit("no stereo_pothole data folder found; pass one")


def _counts(pred: np.ndarray, label: np.ndarray) -> np.ndarray:
    return np.array([(pred & label).sum(), pred.sum(), label.sum()], np.float64)


def _prf(c: np.ndarray) -> tuple[float, float, float]:
    tp, npred, nlab = c
    p = tp / npred if npred else 0.0
    r = tp / nlab if nlab else 0.0
    return p, r, (2 * tp / (npred + nlab) if npred + nlab else 1.0)


def _report(title: str, frames: list[str], counts: list[np.ndarray], chosen: list[str] | None = None) -> None:
    print(f"== {title}")
    f1s = []
    for i, (name, c) in enumerate(zip(frames, counts)):
        p, r, f = _prf(c)
        f1s.append(f)
        extra = f"  chosen on the other frames: {chosen[i]}" if chosen else ""
        print(f"frame {name}: precision {p:.3f}  recall {r:.3f}  F1 {f:.3f}{extra}")
    pooled = _prf(np.sum(counts, axis=0))[2]
    print(f"mean F1 {np.mean(f1s):.3f}  (min {np.min(f1s):.3f})   pixel-pooled F1 {pooled:.3f}\n")


def main() -> None:
    data = _data_dir()
    frames = sorted(p.stem for p in (data / "disp_tg").glob("*.png"))
    combos = {m: list(itertools.product(tiles, *GRID.values())) for m, tiles in MODELS.items()}
    print(f"{len(frames)} frames from {data}; grid {GRID} x tile_frac {MODELS}\n")
    # per model, frame, combination: tp, predicted, labelled
    table = {m: np.zeros((len(frames), len(combos[m]), 3)) for m in MODELS}
    default = {m: [] for m in MODELS}
    d = SegmentParams()
    for fi, name in enumerate(frames):
        disp = load_disparity(data / "disp_tg" / f"{name}.png")
        label = load_label(data / "label" / f"{name}.png")
        for model, tiles in MODELS.items():
            for tile in tiles:
                z, valid = road_residual(disp, SegmentParams(road_model=model, tile_frac=tile))
                for ci, combo in enumerate(combos[model]):
                    if combo[0] != tile:
                        continue
                    params = SegmentParams(road_model=model, tile_frac=tile, **dict(zip(GRID, combo[1:])))
                    table[model][fi, ci] = _counts(segment_residual(z, valid, params) > 0, label)
                if tile == d.tile_frac or model == "quadratic":
                    default[model].append(_counts(segment_residual(z, valid, SegmentParams(road_model=model)) > 0,
                                                  label))
        print(f"  frame {name} done", file=sys.stderr)
    for model in MODELS:
        t = table[model]
        f1 = 2 * t[..., 0] / np.maximum(t[..., 1] + t[..., 2], 1)
        held, chosen = [], []
        for fi in range(len(frames)):
            train = [j for j in range(len(frames)) if j != fi]
            best = int(np.argmax(f1[train].mean(axis=0)))
            held.append(t[fi, best])
            chosen.append(", ".join(f"{k}={v:g}" for k, v in zip(["tile_frac", *GRID], combos[model][best])))
        _report(f"{model} road model, leave-one-out (parameters chosen on the other frames, scored on the "
                "held-out one)", frames, held, chosen)
        _report(f"{model} road model, shipped defaults (k_seed={d.k_seed:g}, depth_frac={d.depth_frac:g}, "
                f"tile_frac={d.tile_frac:g})",
                frames, default[model])


if __name__ == "__main__":
    main()
