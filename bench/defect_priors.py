#!/usr/bin/env python
"""Measure a survey's defect sizes and distances from its labels: what ``compose --defect-priors``
and ``render --views defects:SHARE:clear:NEAR-FAR`` take to make the twin's frames hold the
defects the real frames hold (issue 22: the twin's defects came from parameters, not from reality).

    .venv/bin/python bench/defect_priors.py ../shared/data/road_defects_br/train [--write roadtwin_core/town/defect_priors/road_defects_br.toml] [--plot docs/realism/defect_priors.png]

Each label image's pixels are back-projected through the survey rig (``render --rig survey``:
height, pitch and field of view estimated from the train frames' lane labels, docs/survey_rig.md)
onto a flat road. Per instance (8-connected component; crack strokes joined by a closing of
``JOIN_PX`` px first: a network is labelled as many strokes): its ground area, its equivalent radius
sqrt(A / pi) (potholes), its extent (cracks: the longer side of the ground points' minimum-area
rectangle) and its median distance ahead of the camera; per labelled pixel its z-depth. Prints
the 10/25/50/75/90th percentiles, the fitted lognormal (median, sigma of the log; drawn within the 2nd
and 98th percentiles) and each class's label range (the z-depth within which 99 % of its labelled
pixels lie: where the annotators stopped labelling, a class map's ``[label_range_m]``).
``--write`` stores the fit as a priors TOML (roadtwin_core/town/param_priors.py). Train labels
only: never measure on a split you report. Not a test.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np

from roadtwin_core.apps.reconstruct.inputs import photo_rig
from roadtwin_photo.rectify import PhotoRig, pixel_ground_area

CLASS_IDS = {"crack": 2, "pothole": 3}        # road_defects_br
JOIN_PX = 21            # crack strokes this close (px at 512x320: ~0.1-0.2 m at 3-5 m ahead) are one network
MIN_PIXELS = 10
QUANTILES = (10, 25, 50, 75, 90)
LABEL_RANGE_Q = 99
MIN_POTHOLE_RADIUS_M = 0.08     # the pothole type's own draw starts at 0.10 m
MIN_CRACK_EXTENT_M = 0.3        # and the crack's at 0.5 m
FITTED = (("pothole", "radius_m", MIN_POTHOLE_RADIUS_M), ("crack", "extent_m", MIN_CRACK_EXTENT_M))


def ground_maps(width: int, height: int, rig: str = "survey") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: ground (x across, y ahead) in metres on a flat road, the ground area it covers
    (m^2) and its z-depth (m, what a class map's ``label_range_m`` limits); NaN where the ray
    misses the road. The photo reconstructor's own back-projection (``reconstruct photos --rig``)."""
    r = PhotoRig(**photo_rig(rig))
    u, v = (g.ravel() for g in np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)))
    xy, _ = r.backproject(u, v, width, height)              # the rig looks along +x, +y to its left
    area = pixel_ground_area(u, v, r, width, height)
    _, depth = r.project(xy, width, height)
    return tuple(a.reshape(height, width) for a in (-xy[:, 1], xy[:, 0], area, depth))


def instances(label: np.ndarray, class_id: int, join_px: int) -> list[np.ndarray]:
    mask = (label == class_id).astype(np.uint8)
    if join_px:
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((join_px, join_px), np.uint8))
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    return [comp == c for c in range(1, n) if stats[c, cv2.CC_STAT_AREA] >= MIN_PIXELS]


def measure(folder: Path, rig: str = "survey") -> dict[str, dict[str, np.ndarray]]:
    """Per class: arrays of equivalent radius, extent and distance ahead (m) of every instance,
    and the z-depth of every labelled pixel (``pixel_depth_m``)."""
    files = sorted((folder / "labels").glob("*.png"))
    if not files:
        raise SystemExit(f"error: {folder}/labels: no label PNGs")
    h, w = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED).shape[:2]
    x, y, area, zdepth = ground_maps(w, h, rig)
    out = {c: {"radius_m": [], "extent_m": [], "distance_m": []} for c in CLASS_IDS}
    depths = {c: [] for c in CLASS_IDS}
    for f in files:
        label = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        for name, cid in CLASS_IDS.items():
            depths[name].append(zdepth[(label == cid) & np.isfinite(zdepth)])
            for m in instances(label, cid, JOIN_PX if name == "crack" else 0):
                m &= np.isfinite(y) & np.isfinite(area)    # the row below the horizon: no area
                if m.sum() < MIN_PIXELS:
                    continue
                pts = np.column_stack([x[m], y[m]]).astype(np.float32)
                out[name]["radius_m"].append(math.sqrt(float(area[m].sum()) / math.pi))
                out[name]["extent_m"].append(float(max(cv2.minAreaRect(pts)[1])))
                out[name]["distance_m"].append(float(np.median(y[m])))
    return {c: {**{k: np.asarray(v) for k, v in d.items()}, "pixel_depth_m": np.concatenate(depths[c])}
            for c, d in out.items()}


def lognormal_fit(v: np.ndarray) -> tuple[float, float, float, float]:
    """(median, sigma of the log, 2nd and 98th percentiles) of positive values."""
    logs = np.log(v[v > 0])
    return float(np.exp(np.median(logs))), float(np.std(logs)), *map(float, np.percentile(v, [2, 98]))


def priors_toml(m: dict, source: str) -> str:
    """The fits as a priors file: the pothole type's ``radius_m`` from the potholes' equivalent
    radius, the crack type's ``extent_m`` (its trunk's length, the network's size) from the
    joined networks' extent; drawn within their 2nd and 98th percentiles (truncated, not clipped:
    no pile-up at the ends), and at least the smallest size the type's mesh holds on a road mesh."""
    rows = [f'source = "{source}"', ""]
    for name, key, floor in FITTED:
        med, sig, lo, hi = fitted(m[name][key], floor)
        rows += [f"[{name}.{key}]   # {len(m[name][key])} instances; drawn within the 2nd-98th percentile, at least {floor} m",
                 f"lognormal = [{med:.3f}, {sig:.3f}]", f"truncate = [{lo:.3f}, {hi:.3f}]", ""]
    return "\n".join(rows)


def fitted(values: np.ndarray, floor: float) -> tuple[float, float, float, float]:
    """The prior as written: the lognormal fit with its lower end raised to ``floor``."""
    med, sig, lo, hi = lognormal_fit(values)
    return med, sig, max(lo, floor), hi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("split", type=Path, help="a dataset split: labels/*.png (road_defects_br ids)")
    ap.add_argument("--rig", default="survey")
    ap.add_argument("--write", type=Path, help="write the fitted priors TOML here")
    ap.add_argument("--plot", type=Path, help="write the figure here (real sizes and distances beside the priors)")
    args = ap.parse_args()
    m = measure(args.split, args.rig)
    print(f"| class | measure | instances | {' | '.join(f'q{q}' for q in QUANTILES)} | lognormal median, sigma |")
    print("|---|---|---|" + "---|" * len(QUANTILES) + "---|")
    for name, d in m.items():
        for key, v in d.items():
            qs = " | ".join(f"{q:.2f}" for q in np.percentile(v, QUANTILES))
            med, sig, _, _ = lognormal_fit(v)
            print(f"| {name} | {key} | {len(v)} | {qs} | {med:.3f}, {sig:.3f} |")
    ranges = ", ".join(f"{c} = {np.percentile(d['pixel_depth_m'], LABEL_RANGE_Q):.1f}" for c, d in m.items())
    print(f"label range (z-depth within which {LABEL_RANGE_Q} % of the labelled pixels lie; a class map's "
          f"[label_range_m]): {ranges}")
    if args.write:
        src = (f"bench/defect_priors.py on {args.split.parent.name}/{args.split.name} labels ({args.rig} rig): potholes' "
               f"equivalent radius, crack networks' extent (strokes within {JOIN_PX} px joined)")
        args.write.parent.mkdir(parents=True, exist_ok=True)
        args.write.write_text(priors_toml(m, src))
        print(f"wrote {args.write}")
    if args.plot:
        from _defect_priors_figure import plot
        fits = {(c, k): fitted(m[c][k], floor) for c, k, floor in FITTED}
        print(f"wrote {plot(m, fits, args.plot)}")


if __name__ == "__main__":
    main()
