#!/usr/bin/env python
"""Estimate the survey camera (height, pitch, field of view) of the real road_defects_br frames
from the ego-lane labels. See docs/survey_rig.md for the geometry and its limits.

For each train frame: the ego-lane region (label 1, holes from defects filled, the largest
blob), its left and right edge per image row, a robust line through each edge (OpenCV
``fitLine``, Huber), rows where an edge leaves the picture dropped. On a flat road seen by a
pinhole camera with no roll, both edges are straight lines meeting at the vanishing point on
the horizon row ``v_h``, and the lane's pixel width grows linearly below it:

    w(v) = (W cos(pitch) / h) * (v - v_h),      tan(pitch) = (c_y - v_h) / f

(W lane width in metres, h camera height, f focal length in pixels, c_y the principal row). So
each frame gives ``v_h`` and the slope ``s = W cos(pitch) / h``. The focal length is not
observable from parallel lane lines on a flat road (the forward scale of the ground plane is
free), so it comes from a plausible sensor (default 60 deg horizontal, `--hfov`); the height
barely depends on it (through cos(pitch)), the pitch does, and the script prints both over a
range of fields of view.

  .venv/bin/python bench/estimate_survey_rig.py                      # ../shared/data/road_defects_br/train
  .venv/bin/python bench/estimate_survey_rig.py --lane-width 3.6 --hfov 55
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from roadtwin_core.datasets.folders import find_pairs, read_label
from roadtwin_photo.lane_rig import frame_estimate   # the per-frame geometry (photo reconstructor's lane_width_m)

def _default_data() -> str:
    """../shared/data/road_defects_br/train beside the checkout (or beside any parent folder)."""
    for parent in Path(__file__).resolve().parents[1:]:
        cand = parent / "shared/data/road_defects_br/train"
        if cand.is_dir():
            return str(cand)
    return "../shared/data/road_defects_br/train"


def rig_from(v_h: float, slope: float, u_vp: float, width: int, height: int, hfov_deg: float, lane_width: float):
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    pitch = math.atan((cy - v_h) / f)              # positive: looking down
    return {"hfov_deg": hfov_deg, "vfov_deg": math.degrees(2 * math.atan(0.5 * height / f)), "f_px": f,
            "pitch_down_deg": math.degrees(pitch), "height_m": lane_width * math.cos(pitch) / slope,
            "yaw_deg": math.degrees(math.atan((u_vp - cx) / f))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder", nargs="?", default=_default_data(), help="labelled frames (default: road_defects_br/train)")
    p.add_argument("--lane-width", type=float, default=3.5, help="lane width in metres (default 3.5)")
    p.add_argument("--hfov", type=float, default=60.0, help="assumed horizontal field of view, degrees (default 60)")
    args = p.parse_args(argv)
    samples = find_pairs(args.folder)
    est, shape = [], None
    for s in samples:
        lab = read_label(s.label, 4)
        shape = lab.shape
        e = frame_estimate(lab == 1)
        if e is not None:
            est.append(e)
    if not est:
        print(f"no frame of {args.folder} has two straight lane edges", file=sys.stderr)
        return 2
    h_img, w_img = shape
    v_h = np.array([e["v_h"] for e in est])
    slope = np.array([e["slope"] for e in est])
    u_vp = np.array([e["u_vp"] for e in est])
    q = lambda a: np.percentile(a, [25, 50, 75])  # noqa: E731
    print(f"{args.folder}: {len(est)} of {len(samples)} frames with two straight lane edges ({w_img}x{h_img})")
    for name, a in (("horizon row v_h (px, 0 = top)", v_h), ("vanishing column u_vp (px)", u_vp),
                    ("lane width slope s (px/px)", slope)):
        lo, med, hi = q(a)
        print(f"  {name:32s} median {med:8.2f}   IQR {lo:8.2f} .. {hi:8.2f}")
    print(f"lane width {args.lane_width} m; per frame with the assumed field of view, then the median:")
    print(f"  {'hfov':>6} {'vfov':>6} {'f_px':>7} {'pitch down':>17} {'height m':>17} {'yaw':>6}")
    for hfov in sorted({40.0, 50.0, 60.0, 70.0, 80.0, args.hfov}):
        rigs = [rig_from(e["v_h"], e["slope"], e["u_vp"], w_img, h_img, hfov, args.lane_width) for e in est]
        pitch = q([r["pitch_down_deg"] for r in rigs])
        height = q([r["height_m"] for r in rigs])
        yaw = np.median([r["yaw_deg"] for r in rigs])
        mark = "  <- preset" if hfov == args.hfov else ""
        print(f"  {hfov:6.1f} {rigs[0]['vfov_deg']:6.1f} {rigs[0]['f_px']:7.1f} "
              f"{pitch[1]:6.1f} ({pitch[0]:4.1f}-{pitch[2]:4.1f}) {height[1]:6.2f} ({height[0]:4.2f}-{height[2]:4.2f}) "
              f"{yaw:6.1f}{mark}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
