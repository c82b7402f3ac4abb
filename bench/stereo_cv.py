"""Leave-one-out cross-validation of the transformed-disparity pothole detector (issue 14, item 5).

The detector (plugins/roadtwin_stereo/segment.py) has two numbers chosen by looking at labels:
``k_seed`` (how deep, in road-noise sigmas, a region must reach to be a pothole) and
``depth_frac`` (where a pothole ends, as a fraction of its own depth). For each of the N frames,
they are chosen on the other N-1 frames (grid search, best mean F1, ties to the first in grid
order) and the held-out frame is scored with them. Everything else is derived from the frame.
Printed: per-frame held-out precision / recall / F1, the chosen parameters per fold, mean F1 and
pixel-pooled F1; then the same for the previous detector (main's fixed constants, which were set
looking at frames 01-05, so its figures on those frames are not held out) and for the new
detector with its shipped defaults.

    PYTHONPATH=.:plugins .venv/bin/python bench/stereo_cv.py [DATA_DIR]

DATA_DIR holds disp_tg/NN.png and label/NN.png (default ../shared/data/stereo_pothole, else
tests/data/stereo_pothole). About 2 minutes on one core for 13 frames.
"""
from __future__ import annotations

import importlib.util
import itertools
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
from roadtwin_stereo.segment import (SegmentParams, load_disparity, load_label,
                                     road_residual, segment_residual)

GRID = {"k_seed": [5.0, 7.5, 10.0, 15.0, 20.0], "depth_frac": [0.0, 0.05, 0.1, 0.15, 0.2, 0.3]}


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


def _old_detector():
    """main's segment.py (the fixed-constant detector) as a module, for comparison."""
    try:
        src = subprocess.run(["git", "-C", str(ROOT), "show", "main:plugins/roadtwin_stereo/segment.py"],
                             capture_output=True, text=True, check=True).stdout
    except (subprocess.CalledProcessError, FileNotFoundError):
        return None
    if "def road_residual" in src:  # main already has this detector
        return None
    path = Path(tempfile.mkdtemp()) / "old_segment.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("old_segment", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["old_segment"] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    data = _data_dir()
    frames = sorted(p.stem for p in (data / "disp_tg").glob("*.png"))
    combos = list(itertools.product(*GRID.values()))
    print(f"{len(frames)} frames from {data}; grid {GRID} ({len(combos)} combinations)\n")
    table = np.zeros((len(frames), len(combos), 3))   # per frame, per combination: tp, predicted, labelled
    default = []
    old = _old_detector()
    old_counts = []
    for fi, name in enumerate(frames):
        disp = load_disparity(data / "disp_tg" / f"{name}.png")
        label = load_label(data / "label" / f"{name}.png")
        z, valid = road_residual(disp)
        for ci, combo in enumerate(combos):
            params = SegmentParams(**dict(zip(GRID, combo)))
            table[fi, ci] = _counts(segment_residual(z, valid, params) > 0, label)
        default.append(_counts(segment_residual(z, valid, SegmentParams()) > 0, label))
        if old is not None:
            old_counts.append(_counts(old.segment_defects(disp) > 0, label))
        print(f"  frame {name} done", file=sys.stderr)
    f1 = 2 * table[..., 0] / np.maximum(table[..., 1] + table[..., 2], 1)
    held, chosen = [], []
    for fi in range(len(frames)):
        train = [j for j in range(len(frames)) if j != fi]
        best = int(np.argmax(f1[train].mean(axis=0)))
        held.append(table[fi, best])
        chosen.append(", ".join(f"{k}={v:g}" for k, v in zip(GRID, combos[best])))
    _report("new detector, leave-one-out (parameters chosen on the other frames, scored on the held-out one)",
            frames, held, chosen)
    d = SegmentParams()
    _report(f"new detector, shipped defaults (k_seed={d.k_seed:g}, depth_frac={d.depth_frac:g})", frames, default)
    if old_counts:
        _report("previous detector (main; fixed constants set looking at frames 01-05: not held out there)",
                frames, old_counts)


if __name__ == "__main__":
    main()
