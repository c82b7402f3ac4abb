"""The stereo half of bench/loop.py (issue 20, item 5): per drive frame, OpenCV SGBM disparity
(refined to sub-pixel by Lucas-Kanade when asked) on the rendered pair, the ``stereo_defects``
reconstructor on it, and the scores against the twin's truth.

The disparity of a frame is computed once (and kept in ``OUT/CASE/disparity_*.npz`` with
``--reuse``; float32 holds SGBM's 1/16 px steps and the refinement's float32 result exactly), so
several detector settings (``--floor``, ``--fuse``) are scored on the same maps. Footprints are scored two
ways: the *detected* footprint (the instance's mask outline on its road plane: what the detector
says is damaged road) and the *model* outline (the mesh's boundary, which mesh.py pads by 30 % of
the mask's radius so that the mesh reaches the road at height 0).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from _loop_data import PAVED

MIN_PX = 30
NEAR_M = 10.0
ROI_M = 15.0           # stereo: image rows whose road lies within this (m)


def _plane_outline(mask: np.ndarray, K: np.ndarray, origin: np.ndarray, normal: np.ndarray,
                   cam_to_world: np.ndarray):
    """A pixel mask's outer contour, each contour pixel's ray met with the plane (camera
    coordinates) through ``origin`` with ``normal``, in world XY (shapely)."""
    import cv2
    from shapely.geometry import Polygon

    cs, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(cs, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)
    rays = np.stack([(c[:, 0] - K[0, 2]) / K[0, 0], (c[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(c))], -1)
    p = rays * ((origin @ normal) / (rays @ normal))[:, None]
    w = p @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
    return Polygon(w[:, :2]).buffer(0) if len(w) >= 3 else Polygon()


def _footprints(fr: dict, result) -> tuple[list, list]:
    """Per model: (detected footprint: its mask's outline, model outline: the mesh boundary)."""
    from shapely.geometry import Polygon

    det, mod = [], []
    for m, inst in zip(result.models, result.instances):
        det.append(_plane_outline(result.labels == m.params["instance"], fr["K"], inst.origin, inst.axes[2],
                                  fr["cam_to_world"]))
        b = inst.to_camera(m.vertices[m.boundary] * [1, 1, 0])
        w = b @ fr["cam_to_world"][:3, :3].T + fr["cam_to_world"][:3, 3]
        mod.append(Polygon(w[:, :2]).buffer(0))
    return det, mod


def _iou(a, b) -> float:
    return a.intersection(b).area / max(a.union(b).area, 1e-12)


def frame_figures(fr: dict, result, instances: dict, truth) -> dict:
    """Per frame: the true potholes in view (>= MIN_PX px, none on the border), found or not,
    footprint IoU (detected and model outline) and depth error of the model whose detected
    footprint overlaps it most; detections lying mostly off any true defect."""
    gt, det = fr["instance"], result.labels > 0
    cam = fr["cam_to_world"][:3, 3]
    border = np.zeros_like(gt, bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    feet, outlines = _footprints(fr, result)
    rows = []
    for iid in np.unique(gt[gt > 0]):
        d = truth.defects.get(instances.get(str(int(iid))))
        px = gt == iid
        if d is None or d["type"] != "pothole" or px.sum() < MIN_PX or (px & border).any():
            continue
        did = instances[str(int(iid))]
        row = {"defect": did, "dist_m": float(np.hypot(*(d["xy"] - cam[:2]))), "found": bool(det[px].mean() >= 0.5),
               "iou": 0.0, "iou_model": 0.0, "depth_err_m": None}
        ious = [_iou(f, truth.footprints[did]) for f in feet]
        if ious and max(ious) > 0:
            k = int(np.argmax(ious))
            row.update(iou=float(ious[k]), iou_model=_iou(outlines[k], truth.footprints[did]),
                       depth_err_m=float(result.models[k].depth_m - d["depth_m"]))
        rows.append(row)
    on_true = gt > 0
    false = sum(1 for i in range(1, int(result.labels.max()) + 1) if on_true[result.labels == i].mean() < 0.5)
    return {"rows": rows, "detections": int(result.labels.max()), "false": false}


def road_rows(fr: dict, truth, reach_m: float) -> int:
    """First image row whose centre ray meets the road within ``reach_m`` (horizontal): the
    region of interest a road-inspection camera looks at (its mounting is known), so the sky,
    trees and far road above it are not modelled as road."""
    T, K = fr["cam_to_world"], fr["K"]
    h = T[2, 3] - truth.height(T[None, :2, 3])[0]
    v = np.arange(fr["left"].shape[0], dtype=np.float64)
    ray = np.stack([np.zeros_like(v), (v - K[1, 2]) / K[1, 1], np.ones_like(v)], -1) @ T[:3, :3].T
    down = ray[:, 2] < 0
    dist = np.where(down, h / np.maximum(-ray[:, 2], 1e-9) * np.hypot(ray[:, 0], ray[:, 1]), np.inf)
    inside = np.flatnonzero(dist <= reach_m)
    return int(inside[0]) if len(inside) else 0


def _crop(fr: dict, v0: int) -> dict:
    out = dict(fr)
    for k in ("left", "right", "instance", "depth", "semantic"):
        out[k] = fr[k][v0:]
    out["K"] = fr["K"].copy()
    out["K"][1, 2] -= v0
    return out


def road_mask(semantic: np.ndarray, classes: list[str]) -> np.ndarray:
    """Paved pixels of the frame's semantic truth, eroded 3 px (stands in for a road
    segmentation network's mask, as ``reconstruct surface --masks`` takes one)."""
    import cv2

    paved = np.isin(semantic, [i for i, n in enumerate(classes) if n in PAVED])
    return cv2.erode(paved.astype(np.uint8), np.ones((7, 7), np.uint8))


def frame_disparity(fr: dict, subpixel: tuple[float, float], reject: tuple[float, float] | None = None) -> np.ndarray:
    """SGBM on the pair (disparity range from the frame's nearest true depth), refined to
    sub-pixel when ``subpixel[0] > 0``: what the reconstructor computes from a left/right pair."""
    from roadtwin_stereo import refine_disparity, sgbm_disparity

    zmin = float(np.nanmin(np.where(fr["depth"] > 0, fr["depth"], np.nan)))
    maxd = max(16, int(16 * np.ceil(1.2 * fr["K"][0, 0] * fr["baseline"] / zmin / 16)))
    d = sgbm_disparity(fr["left"], fr["right"], maxd)
    if subpixel[0] > 0:
        d = refine_disparity(fr["left"], fr["right"], d, subpixel, reject=reject)
    return d.astype(np.float32)


def _summary(rows: list[dict], det: int, false: int, frames: int, per_frame: list[int]) -> dict:
    near = [r for r in rows if r["dist_m"] <= NEAR_M]
    matched = [r for r in near if r["depth_err_m"] is not None]
    iou = np.array([r["iou"] for r in near]) if near else np.zeros(0)
    derr = np.abs([r["depth_err_m"] for r in matched]) if matched else np.zeros(0)
    med = lambda x: float(np.median(x)) if len(x) else float("nan")  # noqa: E731
    return {"frames": frames, "potholes_in_view_10m": len(near), "unique_potholes": len({r["defect"] for r in near}),
            "per_frame_max": max(per_frame or [0]), "per_frame_mean": float(np.mean(per_frame or [0])),
            "found_share": float(np.mean([r["found"] for r in near])) if near else float("nan"),
            "found_share_all_dist": float(np.mean([r["found"] for r in rows])) if rows else float("nan"),
            "iou_median": med(iou), "iou_median_matched": med([r["iou"] for r in matched]),
            "iou_model_median_matched": med([r["iou_model"] for r in matched]), "matched": len(matched),
            "iou_ge_0.8_share": float(np.mean(iou >= 0.8)) if len(iou) else float("nan"),
            "depth_err_median_mm": 1000 * med(derr),
            "depth_err_le_1cm_share": float(np.mean(derr <= 0.01)) if len(derr) else float("nan"),
            "detections": det, "false_detections": false, "rows": near}


def stereo_figures(bag, instances: dict, truth, classes: list[str], subpixel: tuple[float, float],
                   floors: list[tuple[float, float]], cache: Path | None = None,
                   reject: tuple[float, float] | None = None, border_px: int = 0,
                   k_region: float | None = None, refit_k: float | None = None,
                   fuse: tuple[tuple, ...] = ((1, 0),)) -> list[dict]:
    """One summary per (floor_depth_m, floor_area_m2) in ``floors`` x (K, L[, options]) in ``fuse``
    (K pairs fused on each, L of them after it, the options StereoDefects.run_sequence's keywords;
    (1, 0) = each pair alone), all on the same disparity maps."""
    from roadtwin_stereo import StereoDefects

    rec = StereoDefects()
    stored = dict(np.load(cache)) if cache is not None and cache.exists() else {}
    fresh, frames, inputs = {}, [], []
    for k, fr in enumerate(bag.stereo_frames()):
        fr = _crop(fr, road_rows(fr, truth, ROI_M))
        key = f"f{k:03d}"
        disp = stored[key] if key in stored else frame_disparity(fr, subpixel, reject)
        fresh[key] = disp
        inputs.append({"disparity": disp.astype(np.float64), "K": fr["K"], "baseline": fr["baseline"],
                       "road_mask": road_mask(fr["semantic"], classes), "source": f"frame_{k:03d}",
                       "cam_to_world": fr["cam_to_world"]})
        frames.append({n: fr[n] for n in ("instance", "K", "cam_to_world")})   # what scoring needs, not the images
        print(f"  frame {k:03d} read", file=sys.stderr, flush=True)
    if cache is not None and fresh.keys() != stored.keys():
        np.savez(cache, **fresh)
    extra = {} if k_region is None else {"k_region": k_region}
    extra.update({} if refit_k is None else {"road_refit_k": refit_k})
    out = []
    for (depth_m, area_m2), (k_pairs, lookahead, *opts) in [(fl, fu) for fl in floors for fu in fuse]:
        params = rec.Params(floor_depth_m=depth_m, floor_area_m2=area_m2, border_px=border_px, **extra)
        acc = {"rows": [], "det": 0, "false": 0, "per_frame": []}
        for fr, res in zip(frames, rec.run_sequence(inputs, params, fuse_frames=k_pairs, lookahead=lookahead,
                                                           **(opts[0] if opts else {}))):
            f = frame_figures(fr, res, instances, truth)
            acc["rows"] += f["rows"]
            acc["det"] += f["detections"]
            acc["false"] += f["false"]
            acc["per_frame"].append(sum(1 for r in f["rows"] if r["dist_m"] <= NEAR_M))
        out.append(_summary(acc["rows"], acc["det"], acc["false"], len(frames), acc["per_frame"]))
        print(f"  floor {depth_m:g} m, {area_m2:g} m2, fuse {k_pairs}:{lookahead} {opts or ''} scored", file=sys.stderr,
              flush=True)
    return out


def add_kept_map_args(ap, root: Path, cases: str, border_px: int) -> None:
    """The options of the scripts that read the loop's kept disparity maps on the tuning cases
    (bench/loop_missed.py, bench/loop_false_detections.py): where, which cases, which map, and
    the detector's border, region rule and road-model refit."""
    from roadtwin_stereo import StereoDefects

    ap.add_argument("--out", type=Path, default=root / "out" / "loop_tune")
    ap.add_argument("--cases", default=cases)
    ap.add_argument("--tag", default="lk6x2_reject1.3x2", help="the kept map: OUT/CASE/disparity_1280x720_TAG.npz")
    ap.add_argument("--border-px", type=int, default=border_px, help="StereoDefectsParams.border_px")
    ap.add_argument("--k-region", type=float, default=StereoDefects.Params().k_region,
                    help="StereoDefectsParams.k_region (0 = the peak rule alone, the detector before)")
    ap.add_argument("--refit-k", type=float, default=StereoDefects.Params().road_refit_k,
                    help="StereoDefectsParams.road_refit_k (0 = no refit of the road model, the detector before)")
