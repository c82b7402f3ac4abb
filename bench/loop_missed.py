"""Why the loop misses potholes (issue 20, item 5; docs/stereo_detector.md).

For every true pothole view bench/loop.py scores (in view: >= MIN_PX true pixels, none on the
border, within NEAR_M of the camera), on the disparity maps it kept (``--reuse``), the drive's
truth and the detector's own intermediate maps say:

- ``dist`` (m), ``area`` (true footprint, m^2), ``depth`` (true, mm), ``px`` (true pixels);
- ``valid``: share of its true pixels with a disparity the detector can use (matched, not
  rejected, inside the road mask);
- ``merged``: the detection on it also covers another true defect (>= 20 % of that one's pixels);
- ``lum`` / ``tex``: its median grey level over the road's (< SHADOW_LUM: under shadow) and its
  RMS row gradient over the road's median (< LOW_TEX: low texture);
- the score map there (px, 10th percentile of the dip over its pixels, > 0 = below the road):
  ``dip_true`` (the renderer's depth as disparity, under the true road: an affine plane fitted to
  that disparity on a ring RING_PX around it: a plane's disparity is affine in (u, v)),
  ``dip_meas`` (the measured map under the same true road), ``dip_model`` (the measured map under
  the detector's local road model: ``dip_meas - dip_model`` is what the road model absorbed);
  each smoothed as the detector smooths its residual (blur_px), so the three compare,
  ``peak`` (the detector's z there, -10th percentile, in noise units; ``reg_peak``: the same over
  the candidate region on it, which step 5 compares with k_seed; ``reg_sig``: that region's mean
  depth over the noise of such a mean, which step 5c compares with k_region), ``sigma`` (the
  frame's noise unit, px; fused: the median over the pothole of the fused map's per-pixel unit);
- ``stage``: the share of its pixels each stage of segment.py covers: candidates (z < -k_grow,
  opened), regions past k_seed or k_region (no floor, no border; k_region is judged with the
  floor's metric maps), + the floor, + the border rule (= the detector's output); ``cause``: the first stage that loses it (``none``: found);
- ``exact``: whether the same detector finds it on the renderer's exact disparity (matcher or
  detector?), ``x_peak`` its peak there;
- with ``--fuse K[:L]`` every map above is the pair's maps fused with K - 1 other pairs' (L after
  it) as StereoDefects.run_sequence fuses them (fusion.py; the exact disparity's fused the same
  way), and two more columns: ``peak1`` (the pair's own peak, before fusion) and ``pairs`` (pairs
  that saw the pothole, median over its pixels).

    PYTHONPATH=.:plugins .venv/bin/python bench/loop_missed.py [--out out/loop_tune]
        [--cases tune_highway_D_seed23] [--tag lk6x2_reject1.3x2] [--border-px 3] [--k-region K] [--refit-k K]
        [--fuse K[:L]] [--refit-road] [--row-bands N] [--all] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "plugins"), str(ROOT / "bench")]
from _loop_data import Bag, load_truth  # noqa: E402
from _loop_stereo import MIN_PX, NEAR_M, ROI_M, _crop, add_kept_map_args, road_mask, road_rows  # noqa: E402

SHADOW_LUM, LOW_TEX, MERGE_SHARE, RING_PX = 0.6, 0.5, 0.2, (4, 20)
BLUR_PX = 2.0  # SegmentParams.blur_px
STAGES = ("candidate", "seed", "floor", "border")


def road_maps(disp: np.ndarray, mask: np.ndarray, p) -> dict:
    """The reconstructor's residual (roadtwin_stereo/__init__.py ``_residual``): z (noise units),
    valid, sigma (px), the masked raw disparity ``d``."""
    from roadtwin_stereo.segment import road_residual
    from roadtwin_stereo.transform import transform_disparity

    d = np.where(mask > 0, disp, np.nan)
    dt, _ = transform_disparity(d)
    z, valid, sigma = road_residual(dt, _seg(p), with_sigma=True)
    return {"z": z, "valid": valid, "sigma": sigma, "d": d}


def _seg(p):
    from roadtwin_stereo.segment import SegmentParams

    return SegmentParams(k_grow=p.k_grow, k_seed=p.k_seed, k_region=p.k_region, min_depth_m=p.floor_depth_m,
                         min_area_m2=p.floor_area_m2, border_px=p.border_px, refit_k=p.road_refit_k)


def detector_maps(r: dict, K: np.ndarray, baseline: float, p) -> dict:
    """The reconstructor's detection (``_detect``) on a residual ``r`` (:func:`road_maps`, or
    the fused one of :func:`fused_maps`: ``sigma`` per pixel), keeping what it sees: z, sigma,
    the road disparity, and the labels at every stage."""
    from roadtwin_stereo.road_model import metric_road_depth
    from roadtwin_stereo.segment import segment_residual

    z, valid, sigma, d, seg = r["z"], r["valid"], r["sigma"], r["d"], _seg(p)
    metric = metric_road_depth(z * sigma, d, valid & (z > -seg.k_grow), K, baseline)
    low = segment_residual(z, valid, replace(seg, k_seed=0.0, k_region=0.0, min_depth_m=0, min_area_m2=0,
                                             border_px=0, close_px=0, depth_frac=0))
    stages = {"candidate": low,
              "seed": segment_residual(z, valid, replace(seg, min_depth_m=0, min_area_m2=0, border_px=0), metric),
              "floor": segment_residual(z, valid, replace(seg, border_px=0), metric),
              "border": segment_residual(z, valid, seg, metric)}
    return {**r, "road_px": d - z * sigma, "stages": stages}


def fused_maps(r: dict, ev, others: list, p, options=None) -> dict:
    """The residual ``r`` of one pair (evidence ``ev``) fused with ``others``' evidence as
    StereoDefects.run_sequence fuses it (fusion.fused_residual), plus ``pairs``: pairs per pixel,
    and ``z1``: the pair's own z."""
    from roadtwin_stereo.fusion import FrameFusion, fused_residual

    z, valid, scale, count = fused_residual(FrameFusion(others), ev, r["z"], r["valid"], r["sigma"], _seg(p), options)
    return {**r, "z": z, "valid": valid, "sigma": scale, "pairs": count, "z1": r["z"]}


def ring_plane(d_true: np.ndarray, px: np.ndarray, others: np.ndarray) -> np.ndarray:
    """The true road's disparity over ``px``: an affine fit (u, v) to ``d_true`` on a ring
    RING_PX around it, off every other true defect (``others``)."""
    import cv2

    grow = lambda r: cv2.dilate(px.astype(np.uint8), cv2.getStructuringElement(  # noqa: E731
        cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)).astype(bool)
    ring = grow(RING_PX[1]) & ~grow(RING_PX[0]) & ~others & np.isfinite(d_true)
    v, u = np.nonzero(ring)
    if len(v) < 10:
        return np.full(px.shape, np.nan)
    a = np.column_stack([u, v, np.ones(len(u))]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(a, d_true[v, u], rcond=None)
    vv, uu = np.mgrid[0:px.shape[0], 0:px.shape[1]]
    return coef[0] * uu + coef[1] * vv + coef[2]


def _smooth(x: np.ndarray, valid: np.ndarray, blur_px: float) -> np.ndarray:
    from roadtwin_stereo.road_model import smooth_valid as smooth

    return smooth(np.where(valid & np.isfinite(x), x, 0.0), valid & np.isfinite(x), blur_px)


def _dip(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.percentile(x, 90)) if len(x) else float("nan")


def _region_peak(z: np.ndarray, valid: np.ndarray, cand: np.ndarray, px: np.ndarray) -> tuple[float, float]:
    """Step 5's peak (-10th percentile of z) and step 5c's significance (its mean depth over the
    noise of such a mean, compared with k_region) of the candidate region covering most of ``px``."""
    from roadtwin_stereo.road_model import region_significance

    labs, n = np.unique(cand[px & (cand > 0)], return_counts=True)
    if not len(labs):
        return float("nan"), float("nan")
    reg = cand == labs[np.argmax(n)]
    lab = reg.astype(np.int32)
    return float(-np.percentile(z[reg], 10)), float(region_significance(z, lab, 2, valid & (np.abs(z) < 3.0))[1])


def _grey(img: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32) if img.ndim == 3 else img.astype(np.float32)


def view_rows(fr: dict, maps: dict, exact: dict, instances: dict, truth, classes: list[str]) -> list[dict]:
    """One row per true pothole view the loop scores."""
    import cv2

    gt = fr["instance"]
    cam = fr["cam_to_world"][:3, 3]
    border = np.zeros(gt.shape, bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    grey = _grey(fr["left"])
    tex = np.sqrt(cv2.GaussianBlur(np.gradient(grey, axis=1) ** 2, (0, 0), sigmaX=6, sigmaY=2))
    road = road_mask(fr["semantic"], classes).astype(bool) & (gt == 0)
    road_grey, road_tex = float(np.median(grey[road])), float(np.median(tex[road]))
    with np.errstate(divide="ignore", invalid="ignore"):
        d_true = np.where(fr["depth"] > 0, fr["K"][0, 0] * fr["baseline"] / fr["depth"], np.nan)
    final = maps["stages"]["border"]
    rows = []
    for iid in np.unique(gt[gt > 0]):
        did = instances.get(str(int(iid)))
        d = truth.defects.get(did)
        px = gt == iid
        if d is None or d["type"] != "pothole" or px.sum() < MIN_PX or (px & border).any():
            continue
        dist = float(np.hypot(*(d["xy"] - cam[:2])))
        if dist > NEAR_M:
            continue
        cover = {s: float((maps["stages"][s][px] > 0).mean()) for s in STAGES}
        cause = "none" if cover["border"] >= 0.5 else next(s for s in STAGES if cover[s] < 0.5)
        if cause == "candidate" and maps["valid"][px].mean() < 0.5:
            cause = "no_disparity"
        merged = 0
        for lab in np.unique(final[px]):
            if lab == 0:
                continue
            reg = final == lab
            others = [j for j in np.unique(gt[reg]) if j not in (0, iid) and (reg[gt == j]).mean() >= MERGE_SHARE]
            merged += len(others)
        true_road = ring_plane(d_true, px, (gt > 0) & ~px)
        under_true = _smooth(true_road - fr["disp"], maps["valid"], BLUR_PX)  # as the detector smooths its residual
        exact_dip = _smooth(true_road - d_true, np.isfinite(d_true), BLUR_PX)
        zpx = maps["z"][px][maps["valid"][px]]
        reg_peak, reg_sig = _region_peak(maps["z"], maps["valid"], maps["stages"]["candidate"], px)
        sigma = maps["sigma"] if np.ndim(maps["sigma"]) == 0 else np.nanmedian(maps["sigma"][px & maps["valid"]])
        fused = {}
        if "z1" in maps:   # fused: the pair's own peak and how many pairs saw the pothole
            z1 = maps["z1"][px][maps["valid"][px]]
            fused = {"peak1": float(-np.percentile(z1, 10)) if len(z1) else np.nan,
                     "pairs": float(np.median(maps["pairs"][px]))}
        rows.append({
            "frame": fr["k"], "defect": did, "dist": dist, "area": float(truth.footprints[did].area),
            "depth": 1000 * d["depth_m"], "px": int(px.sum()), "valid": float(maps["valid"][px].mean()),
            "merged": merged, "lum": float(np.median(grey[px])) / road_grey,
            "tex": float(np.sqrt(np.mean(tex[px] ** 2))) / road_tex,
            "dip_true": _dip(exact_dip[px]), "dip_meas": _dip(np.where(maps["valid"], under_true, np.nan)[px]),
            "dip_model": _dip(np.where(maps["valid"], -maps["z"] * maps["sigma"], np.nan)[px]),
            "peak": float(-np.percentile(zpx, 10)) if len(zpx) else np.nan,
            "reg_peak": reg_peak, "reg_sig": reg_sig, "sigma": float(sigma), **fused,
            **{f"cov_{s}": c for s, c in cover.items()}, "cause": cause,
            "exact": bool((exact["stages"]["border"][px] > 0).mean() >= 0.5),
            "exact_peak": float(-np.percentile(exact["z"][px][exact["valid"][px]], 10))
            if exact["valid"][px].any() else np.nan})
    return rows


def _frames(out: Path, case: str, maps, truth, classes: list[str]):
    """Per frame: the cropped frame, its kept map as ``disp`` and the renderer's depth as a
    disparity, ``exact_disp``."""
    for k, fr in enumerate(Bag(out / case / "drive").stereo_frames()):
        fr = _crop(fr, road_rows(fr, truth, ROI_M))
        fr["k"] = k
        fr["disp"] = maps[f"f{k:03d}"].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            fr["exact_disp"] = np.where(fr["depth"] > 0, fr["K"][0, 0] * fr["baseline"] / fr["depth"], np.nan)
        yield fr


def case_rows(out: Path, case: str, tag: str, params, fuse: tuple[int, int] = (1, 0),
              options=None) -> list[dict]:
    """The rows of one case; ``fuse`` = (K, L): each pair's maps fused as StereoDefects.run_sequence
    fuses them (fusion.py; the exact disparity's maps fused the same way), with ``options``
    (fusion.FusionOptions)."""
    from roadtwin_stereo.fusion import fused_sequence, pair_evidence

    cache = out / case / f"disparity_1280x720_{tag}.npz"
    if not cache.exists():
        print(f"{cache}: no kept disparity maps (run bench/loop.py --reuse first)", file=sys.stderr)
        sys.exit(2)
    summary = json.loads((out / case / "drive" / "summary.json").read_text())
    classes, truth = summary["classes"], load_truth(out / case / "town" / "town.usda")
    maps, rows = np.load(cache), []

    def prepare(fr):
        mask = road_mask(fr["semantic"], classes)
        res = [road_maps(fr[n], mask, params) for n in ("disp", "exact_disp")]
        evs = [pair_evidence(r["z"], r["valid"], r["sigma"], r["d"], fr["K"], fr["baseline"], fr["cam_to_world"],
                             params.k_grow, _seg(params).blur_px) if fuse[0] > 1 else None for r in res]
        return (fr, res, evs), evs

    def detect(state, evs, others):
        fr, res, _ = state
        if fuse[0] > 1:
            res = [fused_maps(r, ev, [o[j] for o in others], params, options)
                   for j, (r, ev) in enumerate(zip(res, evs))]
        m, e = (detector_maps(r, fr["K"], fr["baseline"], params) for r in res)
        print(f"  {case} frame {fr['k']:03d}", file=sys.stderr, flush=True)
        return [{"case": case, **r} for r in view_rows(fr, m, e, summary["instances"], truth, classes)]

    for got in fused_sequence(_frames(out, case, maps, truth, classes), prepare, detect, *fuse):
        rows += got
    return rows


def absorbed(rows: list[dict]) -> float:
    """Median share of the measured dip (``dip_meas``) the detector's road model took
    (``dip_meas - dip_model``), over the views with a measured dip."""
    a = [(r["dip_meas"] - r["dip_model"]) / r["dip_meas"] for r in rows if r["dip_meas"] > 0]
    return float(np.median(a)) if a else float("nan")


def print_table(rows: list[dict], show_all: bool) -> None:
    cols = ("frame", "defect", "dist", "area", "depth", "px", "valid", "merged", "lum", "tex", "dip_true", "dip_meas",
            "dip_model", "peak", "reg_peak", "reg_sig", "sigma", "cov_candidate", "cov_seed", "cov_floor", "cov_border",
            "cause", "exact", "exact_peak")
    cols += ("peak1", "pairs") if rows and "peak1" in rows[0] else ()
    head = {"cov_candidate": "c_cand", "cov_seed": "c_seed", "cov_floor": "c_flr", "cov_border": "c_out",
            "exact_peak": "x_peak"}
    fmt = {"dist": "{:.1f}", "area": "{:.3f}", "depth": "{:.0f}", "valid": "{:.2f}", "lum": "{:.2f}", "tex": "{:.2f}",
           "dip_true": "{:.2f}", "dip_meas": "{:.2f}", "dip_model": "{:.2f}", "peak": "{:.1f}", "reg_peak": "{:.1f}",
           "sigma": "{:.3f}",
           "reg_sig": "{:.1f}", "exact_peak": "{:.1f}", "peak1": "{:.1f}", "pairs": "{:.0f}"}
    shown = [r for r in rows if show_all or r["cause"] != "none"]
    print(" ".join(f"{head.get(c, c)[:7]:>7s}" for c in cols))
    for r in sorted(shown, key=lambda r: (r["case"], r["dist"])):
        cells = []
        for c in cols:
            v = r[c]
            cells.append((fmt.get(c, "{:.2f}" if c.startswith("cov") else "{}")).format(v)[-7:])
        print(" ".join(f"{x:>7s}" for x in cells))
    found = [r for r in rows if r["cause"] == "none"]
    print(f"\n{len(rows)} views within {NEAR_M:g} m, found {len(found)} ({100 * len(found) / max(len(rows), 1):.1f} %); "
          f"found on the exact disparity by the same detector: {sum(r['exact'] for r in rows)}")
    print("misses by cause: " + ", ".join(f"{k} {v}" for k, v in Counter(r["cause"] for r in rows
                                                                        if r["cause"] != "none").items()))
    miss = [r for r in rows if r["cause"] != "none"]
    print("dip the road model absorbed ((measured - under the model) / measured), median: " + ", ".join(
        f"{name} {100 * absorbed(rs):.0f} %" for name, rs in (("all views", rows), ("missed", miss), ("found", found))))
    if miss:
        med = lambda k, rs: float(np.nanmedian([r[k] for r in rs])) if rs else float("nan")  # noqa: E731
        for name, rs in (("missed", miss), ("found", found)):
            print(f"  {name:6s}: median dist {med('dist', rs):.1f} m, area {med('area', rs):.3f} m2, depth "
                  f"{med('depth', rs):.0f} mm, valid {med('valid', rs):.2f}, dip true {med('dip_true', rs):.2f} px, "
                  f"measured {med('dip_meas', rs):.2f} px, under the model {med('dip_model', rs):.2f} px, peak {med('peak', rs):.1f} sigma, sigma "
                  f"{med('sigma', rs):.3f} px, merged {sum(r['merged'] > 0 for r in rs)}, shadow "
                  f"{sum(r['lum'] < SHADOW_LUM for r in rs)}, low texture {sum(r['tex'] < LOW_TEX for r in rs)}")


def main() -> None:
    from roadtwin_stereo import FusionOptions, StereoDefects

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_kept_map_args(ap, ROOT, "tune_highway_D_seed23", border_px=3)     # bench/loop.py's border
    ap.add_argument("--all", action="store_true", help="list found views too")
    ap.add_argument("--json", type=Path, help="write the rows here")
    ap.add_argument("--fuse", default="1", help="K[:L]: each pair's maps fused with K - 1 others, L of them after it, "
                    "as StereoDefects.run_sequence fuses them (bench/loop.py --fuse; 1 = each pair alone)")
    ap.add_argument("--refit-road", action="store_true", help="with --fuse: the local road model fitted again on the "
                    "fused map (fusion.FusionOptions.refit_road)")
    ap.add_argument("--row-bands", type=int, default=1, help="with --fuse: the fused map's noise measured in this many "
                    "bands of rows too (fusion.FusionOptions.row_bands; 1 = by predicted gain only)")
    args = ap.parse_args()
    try:
        fuse = tuple(int(x) for x in (args.fuse + ":0").split(":")[:2])
    except ValueError:
        fuse = (0, 0)
    if fuse[0] < 1 or not 0 <= fuse[1] < fuse[0]:
        ap.error(f"--fuse: K[:L] with K >= 1 and 0 <= L < K expected, got {args.fuse!r}")
    params = StereoDefects.Params(texture=False, border_px=args.border_px, k_region=args.k_region,
                                  road_refit_k=args.refit_k)
    options = FusionOptions(refit_road=args.refit_road, row_bands=args.row_bands)
    rows = [r for case in args.cases.split(",") for r in case_rows(args.out, case, args.tag, params, fuse, options)]
    print_table(rows, args.all)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))


if __name__ == "__main__":
    main()
