"""Defect pixels from a transformed disparity map (core-free: numpy + OpenCV + scipy).

After Fan et al.'s disparity transformation the road is (nearly) constant and a pothole is a
region of *lower* disparity (farther = deeper). What changes between roads and days -- the
disparity range and its per-frame normalisation, the leftover roll and pitch, the noise and
texture of the surface, the share of the frame that is road, the size and depth of the pothole --
is absorbed by measuring every threshold in units the frame itself supplies:

1. **Invalid pixels.** 0 or NaN = no disparity. Fan et al.'s 16-bit maps are min-max normalised
   per frame (units gone); nothing below depends on an affine change of the values.
2. **Road surface model.** A quadratic surface ``r(u, v)`` fitted by iterated trimmed least
   squares (Fan et al. T-IP 2019 fit a quadratic road model too). Potholes lie only *below* the
   road, so the first fit starts on the pixels above the frame's median residual of a plane: a
   pothole or a non-road area covering a large share of the frame cannot bend the start.
   Trimming at 3 robust sigma then converges to the dominant (road) surface; it absorbs the
   roll/pitch the 1-D transformation leaves.
   Since issue 20 (``road_model="local"``, the default) this global surface is only the start: a
   local robust correction (tiles, rows; :mod:`.road_model`) follows the road's undulation, and
   sigma is the small-scale noise of what is left (step 3 there), not of the quadratic's residual;
   with ``refit_k`` (the reconstructor's metric inputs) it is refitted without the regions
   reaching ``refit_k`` below and above the road (step 5 there: a pothole it left in the fit was
   absorbed, a median 28 % of its dip on the loop's tuning highway).
3. **Road noise sigma** (``road_model="quadratic"``). The residual ``e = d - r`` is smoothed by a normalised Gaussian (sigma
   ``blur_px``, ignoring invalid pixels); ``s`` = 1.4826 x MAD over the *road inliers* of the fit
   (not over every valid pixel: kerbs, verges and potholes would inflate it). ``z = e / s``.
4. **Candidates.** ``z < -k_grow`` with ``k_grow = 3``: the one-sided 3-sigma rule (0.13 % of road
   pixels), a convention, not read off labels. Opening removes speckle.
5. **Which regions are potholes.** A candidate region is kept if its peak depth (10th percentile
   of ``z`` over it) exceeds ``k_seed`` road sigmas -- a depth relative to this frame's noise,
   whatever the region's size (the earlier detector demanded a fixed seed *area* of 0.2 % of the
   image, which a small pothole on another road does not reach).
5b. **A physical floor** (metric maps only: a raw disparity with K and baseline). Noise-relative
   thresholds fall with the map's noise: on a clean map (sub-pixel matching) benign road shape
   -- crown, camber, undulation the local model leaves, a few mm -- passes step 5. So a kept
   region must also reach ``min_depth_m`` below the local road model (90th percentile of its
   pixels' depth in metres, :func:`~.road_model.metric_road_depth`) and cover ``min_area_m2``
   of road. A transformed, normalised map has lost its units: there the floor is not applied.
   (On bench/loop.py's drives it removes few: their false detections are local 0.2-0.5 px
   matching errors, metrically as deep as potholes; docs/stereo_detector.md.)
5c. **A region's mean** (metric maps only, ``k_region``; issue 20). A far pothole is a 0.3-0.6 px
   dip over 500-2000 px: 5-9 sigma at its deepest, as deep as the matcher's small false dips,
   so step 5 misses it (bench/loop_missed.py: 45 of the 49 misses on the loop's tuning highway
   had a measured dip within 0.1 px of the true one). A candidate region is also kept when its
   mean depth exceeds ``k_region`` times the noise of a mean over as many road pixels, measured on
   the frame at block sizes 2-64 px (:func:`~.road_model.mean_noise`: the matcher's errors are correlated,
   so that noise falls slower than 1 / sqrt(N)). Only where the physical floor of step 5b
   guards it: on the 13 normalised real frames the rule finds the road's other, unlabelled dips
   (mean F1 0.911 -> 0.875 at 12), and there is no metric floor there to hold them back.
6. **Where a pothole ends.** Each kept region is cut at ``max(k_grow, depth_frac x its own peak
   depth)``: a deep pothole's edge is set relative to that pothole, so a shallow sag of the road
   around it (seen as twice the labelled area on other roads) does not join it.
7. **Invalid pixels inside.** Stereo matching fails on pothole walls and bottoms (27-42 % of
   the labelled pixels are 0 in the real frames). An invalid blob joins a pothole when more of
   the valid pixels bordering it belong to the pothole than lie at road level (a majority vote
   of its neighbours, no threshold) and it does not touch the image border; then a closing
   (``close_px``) and hole filling.
8. **Instances.** 8-connected components, renumbered 1..N.

``k_seed``, ``depth_frac`` and ``tile_frac`` are the numbers chosen by looking at labels;
``bench/stereo_cv.py`` chooses them by leave-one-out cross-validation and reports F1 only on held-out
frames (docs/stereo_detector.md, which also says why k_seed stays 10 where the folds chose 15);
depth_frac 0: the labels put a pothole's edge at road level, z ~ 0; depth_frac > 0 is the knob for
roads whose potholes come out too wide.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage as ndi

from roadtwin_core import RoadtwinError

from .road_model import deep_regions, local_road_residual, region_significance, robust_sigma


@dataclass
class SegmentParams:
    k_grow: float = 3.0          # candidate pixel: below the road by more than k_grow road sigmas
    k_seed: float = 10.0         # a kept region's peak depth exceeds k_seed road sigmas
    k_region: float = 0.0        # or its mean depth exceeds k_region x the noise of a mean over as many road pixels
                                 # (metric maps only, where the physical floor guards it; 0 = off)
    depth_frac: float = 0.0      # a region's edge: max(k_grow, depth_frac x its peak depth) sigmas
    min_area_frac: float = 0.0   # optional floor on a region's area (fraction of the image); 0 = off
    blur_px: float = 2.0         # Gaussian sigma of the residual smoothing (pixels)
    open_px: int = 3             # opening radius (speckle removal)
    close_px: int = 5            # closing radius (gap bridging)
    surface_degree: int = 2      # the global surface's polynomial degree in (u, v)
    road_model: str = "local"    # "local": global surface + robust tile correction (road_model.py); "quadratic"
    tile_frac: float = 0.0625    # local model: tile side as a fraction of the frame's shorter side
    model_iters: int = 3         # local model: rounds of masking candidates and refitting
    mask_k: float = 10.0         # local model: regions reaching this many sigmas are masked from the road fit
    refit_k: float = 0.0         # local model: refit without the depressions and bumps reaching this many sigmas,
                                 # each down to its k_grow rim (road_model.py step 5; 0 = off)
    min_depth_m: float = 0.0     # physical floor (metric maps only): a kept region reaches this far below the road
    min_area_m2: float = 0.0     # physical floor (metric maps only): a kept region covers this much road
    border_px: int = 0           # regions reaching within this of the map's edge are dropped (0 = keep)


def load_disparity(path: str | Path, scale: float = 1.0) -> np.ndarray:
    """A disparity map as float64 with NaN for invalid pixels.

    16-bit PNG (value / ``scale``; 0 = invalid; KITTI-style raw maps use scale 256, the
    normalised transformed maps of Fan et al. any scale since detection is scale-free), 8-bit
    PNG, ``.npy`` or ``.pfm`` float maps (non-finite or <= 0 invalid for PNG only)."""
    import cv2

    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such disparity map")
    if path.suffix.lower() == ".npy":
        d = np.load(path).astype(np.float64)
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise RoadtwinError(f"{path}: cannot read as an image")
        if img.ndim == 3:
            raise RoadtwinError(f"{path}: disparity must be a single-channel image, got {img.shape[2]} channels")
        d = img.astype(np.float64)
        if img.dtype in (np.uint8, np.uint16):
            d[img == 0] = np.nan
            d /= scale
        if path.suffix.lower() == ".pfm":
            d = np.flipud(d)
    if d.ndim != 2:
        raise RoadtwinError(f"{path}: disparity must be 2-D, got shape {d.shape}")
    d[~np.isfinite(d)] = np.nan
    if not np.isfinite(d).any():
        raise RoadtwinError(f"{path}: no valid disparity (every pixel invalid): no road to model")
    return d


def load_label(path: str | Path) -> np.ndarray:
    """A pothole label image as a bool mask (any non-zero channel = pothole)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(path)
    return (img.max(axis=-1) if img.ndim == 3 else img) > 0


def _poly_design(u: np.ndarray, v: np.ndarray, degree: int) -> np.ndarray:
    cols = [np.ones_like(u)]
    for p in range(1, degree + 1):
        for q in range(p + 1):
            cols.append(u ** (p - q) * v ** q)
    return np.stack(cols, axis=-1)


def fit_road_surface(d: np.ndarray, degree: int = 2, step: int = 4, iters: int = 10,
                     return_inliers: bool = False):
    """Robust polynomial surface r(u, v) over the valid pixels of ``d`` (NaN = invalid).

    Least squares on a subsampled grid; the first fit uses only pixels above the median residual
    of a plane (potholes lie below the road), then refits on the pixels within 3 robust sigma
    until the inlier set stops changing. With ``return_inliers`` also returns a full-size mask of
    the road inliers (pixels within 3 robust sigma of the final surface)."""
    h, w = d.shape
    vv, uu = np.mgrid[0:h:step, 0:w:step]
    z = d[::step, ::step]
    ok = np.isfinite(z)
    un, vn = uu[ok] / w - 0.5, vv[ok] / h - 0.5
    a = _poly_design(un, vn, degree)
    zm = z[ok]
    a1 = _poly_design(un, vn, 1)
    c1, *_ = np.linalg.lstsq(a1, zm, rcond=None)
    r1 = zm - a1 @ c1
    inl = r1 >= np.median(r1)
    coef = np.zeros(a.shape[1])
    s = 1.0
    for _ in range(iters):
        coef, *_ = np.linalg.lstsq(a[inl], zm[inl], rcond=None)
        r = zm - a @ coef
        s = robust_sigma(r[inl])
        new = np.abs(r - np.median(r[inl])) < 3 * s
        if new.sum() < a.shape[1] * 3 or np.array_equal(new, inl):
            break
        inl = new
    out = np.empty((h, w))
    for r0 in range(0, h, 256):  # row blocks: bounded memory
        v, u = np.mgrid[r0:min(h, r0 + 256), 0:w]
        out[r0:r0 + len(v)] = _poly_design(u / w - 0.5, v / h - 0.5, degree) @ coef
    if not return_inliers:
        return out
    e = d - out
    med = float(np.median(e[np.isfinite(e)][::step])) if np.isfinite(e).any() else 0.0
    return out, np.isfinite(e) & (np.abs(e - med) < 3 * s)


def road_residual(disp: np.ndarray, params: SegmentParams | None = None, with_sigma: bool = False):
    """(z, valid): the smoothed residual to the road model in units of the road's own noise
    sigma (road level = 0, potholes negative), and the mask of valid pixels. With
    ``road_model="local"`` (default) the global surface is corrected by the local robust model
    of :mod:`.road_model` and sigma is the small-scale (high-pass) noise. ``with_sigma``: also
    sigma itself (``z * sigma`` is the residual in the map's units, px for a raw disparity)."""
    import cv2

    p = params or SegmentParams()
    if p.road_model not in ("local", "quadratic"):
        raise ValueError(f"road_model must be 'local' or 'quadratic', got {p.road_model!r}")
    d = np.asarray(disp, dtype=np.float64).copy()
    d[~np.isfinite(d) | (d == 0)] = np.nan
    valid = np.isfinite(d)
    if valid.sum() < 100:
        return (np.zeros(d.shape), valid, 1.0) if with_sigma else (np.zeros(d.shape), valid)
    surface, road = fit_road_surface(d, p.surface_degree, return_inliers=True)
    e = np.where(valid, d - surface, 0.0)
    res0 = e
    if p.blur_px > 0:
        num = cv2.GaussianBlur(e, (0, 0), p.blur_px)
        den = cv2.GaussianBlur(valid.astype(np.float64), (0, 0), p.blur_px)
        res0 = np.where(den > 0.2, num / np.maximum(den, 1e-9), 0.0)
    ref = res0[road] if road.sum() > 100 else res0[valid]
    med = float(np.median(ref))
    sigma = robust_sigma(ref)
    z = np.where(valid, (res0 - med) / sigma, 0.0)
    if p.road_model == "local":
        z, _, sigma = local_road_residual(e, valid, deep_regions(z, valid, p.k_grow, p.mask_k), k_grow=p.k_grow,
                                          k_peak=p.mask_k, tile_frac=p.tile_frac, blur_px=p.blur_px,
                                          iters=p.model_iters, refit_k=p.refit_k, open_px=p.open_px)
    return (z, valid, sigma) if with_sigma else (z, valid)


def segment_residual(z: np.ndarray, valid: np.ndarray, params: SegmentParams | None = None,
                     metric: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Instance labels (int32, 0 = road) from :func:`road_residual`'s output (steps 4-8 of the
    module docstring); split off so a parameter sweep reuses one surface fit. ``metric``:
    (depth_m, area_m2) per pixel (:func:`~.road_model.metric_road_depth`), for the physical
    floor (step 5b); without it (a transformed, normalised map has no metric scale) the floor
    is not applied."""
    import cv2

    p = params or SegmentParams()
    out = np.zeros(z.shape, np.int32)
    if valid.sum() < 100:
        return out
    low = (z < -p.k_grow) & valid
    if p.open_px > 0:
        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * p.open_px + 1,) * 2)
        low = cv2.morphologyEx(low.astype(np.uint8), cv2.MORPH_OPEN, ker).astype(bool)
    n, lab = cv2.connectedComponents(low.astype(np.uint8), connectivity=8)
    if n <= 1:
        return out
    # step 5: peak depth per region (10th percentile of z), step 6: edge relative to it
    order = np.argsort(lab.ravel(), kind="stable")
    zs = z.ravel()[order]
    counts = np.bincount(lab.ravel(), minlength=n)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    peak = np.zeros(n)
    for i in range(1, n):
        zi = zs[starts[i]:starts[i] + counts[i]]
        peak[i] = -np.percentile(zi, 10)
    keep = peak > p.k_seed
    if p.k_region > 0 and metric is not None:  # step 5c: only where the physical floor guards it
        keep |= region_significance(z, lab, n, valid & (np.abs(z) < p.k_grow)) > p.k_region
    keep[0] = False
    if p.min_area_frac > 0:
        keep &= counts >= p.min_area_frac * z.size
    if metric is not None and (p.min_depth_m > 0 or p.min_area_m2 > 0):
        keep &= _physical_floor(lab, n, keep, metric, p)
    edge = np.maximum(p.k_grow, p.depth_frac * peak)
    region = keep[lab] & (z < -edge[lab])
    # step 7: invalid blobs mostly bordered by the region join it (not those on the image border)
    n_inv, inv = cv2.connectedComponents((~valid).astype(np.uint8), connectivity=8)
    if n_inv > 1 and region.any():
        ring = cv2.dilate((~valid).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & valid
        near = ndi.grey_dilation(inv, size=(3, 3))  # id of an adjacent invalid blob (largest id wins)
        join = np.bincount(near[ring & region], minlength=n_inv) > 0
        border = np.unique(np.concatenate([inv[0], inv[-1], inv[:, 0], inv[:, -1]]))
        join[border] = False
        join[0] = False
        region |= join[inv]
    if p.close_px > 0:
        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * p.close_px + 1,) * 2)
        region = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_CLOSE, ker).astype(bool)
    region = ndi.binary_fill_holes(region)
    if p.open_px > 0:  # pieces a relative edge cut off that are smaller than the speckle scale
        ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * p.open_px + 1,) * 2)
        region = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_OPEN, ker).astype(bool)
    if p.border_px > 0:
        region = _clear_border(region, p.border_px)
    n, lab = cv2.connectedComponents(region.astype(np.uint8), connectivity=8)
    return lab.astype(np.int32)


def _clear_border(region: np.ndarray, px: int) -> np.ndarray:
    """Regions reaching within ``px`` of the map's edge removed (as scikit-image's ``clear_border``):
    a region cut by the edge has no road rim on that side, so its depth and outline cannot be
    checked against the road around it; a camera driving on sees it whole in a later frame. On
    bench/loop.py's tuning town 34 of 48 false detections touch the crop's edge: far-road (12-15
    m) matching errors that run into its top row (bench/loop_false_detections.py;
    docs/stereo_detector.md)."""
    import cv2

    _, lab = cv2.connectedComponents(region.astype(np.uint8), connectivity=8)
    edge = np.ones(region.shape, bool)
    edge[px:-px, px:-px] = False
    return region & ~np.isin(lab, np.unique(lab[edge & region]))


def _physical_floor(lab: np.ndarray, n: int, keep: np.ndarray, metric: tuple[np.ndarray, np.ndarray],
                    p: SegmentParams) -> np.ndarray:
    """Step 5b: per candidate region, its depth below the local road in metres (the 90th
    percentile of the per-pixel depth: the same robust peak as step 5's 10th percentile of z)
    reaches ``min_depth_m`` and the road it covers reaches ``min_area_m2``."""
    depth, area = metric
    ok = np.ones(n, bool)
    for i in np.flatnonzero(keep):
        px = lab == i
        dm = depth[px]
        dm = dm[np.isfinite(dm)]
        ok[i] = (len(dm) > 0 and np.percentile(dm, 90) >= p.min_depth_m
                 and float(np.nansum(area[px])) >= p.min_area_m2)
    return ok


def segment_defects(disp: np.ndarray, params: SegmentParams | None = None) -> np.ndarray:
    """Instance labels (int32, 0 = road, 1..N = defects) of a transformed disparity map
    (NaN or 0 = invalid). See the module docstring for the method."""
    z, valid = road_residual(disp, params)
    return segment_residual(z, valid, params)


def f1_score(pred: np.ndarray, label: np.ndarray) -> float:
    """Pixel F1 (= Dice) of two boolean masks."""
    pred, label = np.asarray(pred, bool), np.asarray(label, bool)
    tp = float((pred & label).sum())
    den = float(pred.sum() + label.sum())
    return 1.0 if den == 0 else 2 * tp / den
