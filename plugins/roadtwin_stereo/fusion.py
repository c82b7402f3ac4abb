"""Multi-pair fusion of the detector's depth-below-the-road evidence (issue 20, item 5; core-free).

Why: on bench/loop.py's undulating highway most missed pothole views peak at only ~3.5 noise
units below the road in one pair (bench/loop_missed.py): the matcher's noise. A drive sees each
pothole in many consecutive pairs (10 Hz), and the matcher's errors of different pairs are
nearly independent (correlation 0.0-0.17 at the same road point on the tuning highway), so
averaging the depth below the road at one road point over several pairs lowers that noise.

How (docs/stereo_detector.md, "Multi-pair fusion"):

1. per pair, the detector's residual ``z`` under its local road model (noise units,
   road_model.py) and its scale ``s = sigma H / d_road`` (metres per noise unit: the closed form
   of road_model.metric_road_depth), so ``D = -z s`` is the depth below the local road (m);
2. each pixel of the current pair is placed on its road (its ray met at the local model's road
   disparity, smoothed), moved to the world with the pair's pose and projected into each other
   pair (its pose, pinhole K), where ``D`` and ``s`` are read (bilinear over valid pixels only);
3. inverse-variance mean of ``D``, back in the current pair's disparity px;
4. in units of its own noise, *measured* per pixel class (:func:`noise_units`): the road's own
   roughness is the same in every pair and does not average out, and pixels far ahead are seen
   by fewer pairs (the others' crop ends), so a predicted sqrt(K) would overstate the gain
   (:class:`FusionOptions` ``row_bands``: the classes also by image row, i.e. by range);
5. (:class:`FusionOptions` ``refit_road``; off by default) the local road model fitted again on
   the fused depth below each pair's road plane: each pair's own model absorbs part of a
   pothole its noise hides, and fusing absorbed evidence keeps it absorbed.

The detector's steps 4-8 (segment.py) then run on the fused map, so the pair gets the
detections. Poses are camera-to-world 4 x 4 (OpenCV axes: X right, Y down, Z forward).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .road_model import deep_regions, local_road_residual, robust_sigma, row_levels, smooth_valid

ROAD_BLUR_PX = 4.0  # smoothing of the road disparity that places a pixel on the road (its noise, not its shape)


@dataclass
class PairEvidence:
    """One pair's evidence: ``depth_m`` below its local road (NaN = invalid), ``noise_m`` (its
    standard deviation), ``m_per_px`` (metres below the road per px of disparity residual),
    ``road_disp`` (road disparity, px, every pixel), calibration and pose; ``plane_depth_m``: the
    depth below the pair's road *plane* and its rows' levels instead (smoothed as ``depth_m``; what
    its local road model's tiles absorbed is still in it), for :func:`fused_residual`'s ``refit_road``."""

    depth_m: np.ndarray
    noise_m: np.ndarray
    m_per_px: np.ndarray
    road_disp: np.ndarray
    K: np.ndarray
    baseline: float
    cam_to_world: np.ndarray
    plane_depth_m: np.ndarray | None = None


def _road_plane(road_disp: np.ndarray, ok: np.ndarray, K: np.ndarray, baseline: float) -> tuple[np.ndarray, float]:
    """(affine road disparity a u + b v + c over the frame, camera height H): a plane's
    disparity is affine in (u, v) (road_model.metric_road_depth gives the closed form)."""
    v, u = np.nonzero(ok)
    pick = slice(None, None, max(1, len(v) // 50000))
    a = np.column_stack([u[pick], v[pick], np.ones(len(u[pick]))]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(a, road_disp[v[pick], u[pick]], rcond=None)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    g = np.array([coef[0], coef[1] * fy / fx, (coef @ [cx, cy, 1.0]) / fx])
    vv, uu = np.mgrid[0:road_disp.shape[0], 0:road_disp.shape[1]]
    return coef[0] * uu + coef[1] * vv + coef[2], baseline / max(float(np.linalg.norm(g)), 1e-12)


def pair_evidence(z: np.ndarray, valid: np.ndarray, sigma: float, disp: np.ndarray, K: np.ndarray,
                  baseline: float, cam_to_world: np.ndarray, k_grow: float = 3.0,
                  blur_px: float = 2.0, plane_depth: bool = True) -> PairEvidence | None:
    """Step 1 for one pair from segment.road_residual's ``z``, ``valid``, ``sigma`` (px of
    ``disp``, the raw disparity). None when too little road. ``blur_px``: the detector's
    smoothing (SegmentParams.blur_px), applied to ``plane_depth_m`` as it was to ``z``;
    ``plane_depth``: whether to make ``plane_depth_m`` (only ``refit_road`` reads it)."""
    d = np.asarray(disp, np.float64)
    road_px = np.where(valid & np.isfinite(d), d - z * sigma, np.nan)
    ok = np.isfinite(road_px) & (z > -k_grow)
    if ok.sum() < 100:
        return None
    plane, height = _road_plane(road_px, ok, K, baseline)
    road_disp = plane + smooth_valid(np.where(ok, road_px - plane, 0.0), ok, ROAD_BLUR_PX)
    with np.errstate(invalid="ignore", divide="ignore"):
        m_per_px = np.where(road_disp > 0, height / road_disp, np.nan)
    depth = np.where(valid, -z * sigma * m_per_px, np.nan)
    below = None
    if plane_depth:
        off_plane = np.where(valid & np.isfinite(d), d - plane, 0.0)
        off_plane -= row_levels(off_plane, ok)[:, None]   # what is constant along a row is road (road_model.py step 2)
        below_plane = -smooth_valid(off_plane, valid & np.isfinite(d), blur_px)
        below = np.where(valid, below_plane * m_per_px, np.nan).astype(np.float32)
    return PairEvidence(depth.astype(np.float32), (sigma * m_per_px).astype(np.float32), m_per_px, road_disp,
                        np.asarray(K, np.float64), float(baseline), np.asarray(cam_to_world, np.float64), below)


def _lookup(cur: PairEvidence, other: PairEvidence, fields=("depth_m", "noise_m")) -> list[np.ndarray]:
    """Step 2: ``other``'s ``fields`` (default: depth and noise) at the road point of every pixel of ``cur``."""
    import cv2

    h, w = cur.road_disp.shape
    K = cur.K
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = np.where(cur.road_disp > 0, K[0, 0] * cur.baseline / cur.road_disp, np.nan)
    p = np.stack([(uu - K[0, 2]) / K[0, 0] * Z, (vv - K[1, 2]) / K[1, 1] * Z, Z], -1)
    T = np.linalg.inv(other.cam_to_world) @ cur.cam_to_world
    q = p @ T[:3, :3].T + T[:3, 3]
    Ko = other.K
    with np.errstate(divide="ignore", invalid="ignore"):
        front = q[..., 2] > 0.1
        mu = np.where(front, Ko[0, 0] * q[..., 0] / q[..., 2] + Ko[0, 2], -1e6).astype(np.float32)
        mv = np.where(front, Ko[1, 1] * q[..., 1] / q[..., 2] + Ko[1, 2], -1e6).astype(np.float32)
    mu[~np.isfinite(mu)] = -1e6
    mv[~np.isfinite(mv)] = -1e6
    warp = lambda a: cv2.remap(a, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,  # noqa: E731
                               borderValue=0.0)
    ok = np.isfinite(other.depth_m)
    weight = warp(ok.astype(np.float32))   # over the valid neighbours only: no hole around each invalid one
    seen = weight > 0.5

    def get(a: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(seen, warp(np.where(ok, a, 0.0).astype(np.float32)) / weight, np.nan)
    return [get(getattr(other, f)) for f in fields]


class FrameFusion:
    """The ``others`` pairs' evidence (:class:`PairEvidence`, any order), to be fused onto one pair."""

    def __init__(self, others=()) -> None:
        self.others = [e for e in others if e is not None]

    def fuse(self, ev: PairEvidence | None, valid: np.ndarray, field: str = "depth_m"
             ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """Steps 2-3: (the fused depth below the road as a residual in ``ev``'s disparity px, NaN
        off ``valid``, None without evidence; its predicted noise over ``ev``'s alone, <= 1;
        pairs per pixel). ``field``: which depth (``"plane_depth_m"``: below each pair's plane)."""
        if ev is None or getattr(ev, field) is None:
            return None, np.ones(valid.shape), valid.astype(np.int32)
        num, den = np.zeros(valid.shape), np.zeros(valid.shape)
        count = np.zeros(valid.shape, np.int32)
        for dj, nj in [(getattr(ev, field), ev.noise_m)] + [_lookup(ev, o, (field, "noise_m")) for o in self.others
                                                            if getattr(o, field) is not None]:
            ok = np.isfinite(dj) & np.isfinite(nj) & (nj > 0)
            num[ok] += dj[ok] / nj[ok] ** 2
            den[ok] += 1.0 / nj[ok] ** 2
            count += ok
        ok = valid & (den > 0) & (ev.m_per_px > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.where(ok, 1.0 / (np.sqrt(den) * ev.noise_m), 1.0)
            residual = np.where(ok, -(num / den) / ev.m_per_px, np.nan)
        return residual, np.clip(gain, 1e-3, 1.0), count


@dataclass(frozen=True)
class FusionOptions:
    """Choices of the fused map (StereoDefects.run_sequence; the defaults, both off, are the fusion
    as chosen on bench/loop.py's tuning cases, docs/stereo_detector.md): ``refit_road``: step 5, the local
    road model fitted again on the fused map; ``row_bands``: step 4's noise classes also by image
    row, in this many bands of equal pixel count (1: by predicted gain only); ``exclude_k``: step 4
    measured again without the pixels its first pass put this many units or more from the road
    (grown 5 px), so a large pothole does not widen its own noise class (0: off)."""

    refit_road: bool = False
    row_bands: int = 1
    exclude_k: float = 0.0


def _gain_spread(r: np.ndarray, g: np.ndarray, bins: int, at: np.ndarray) -> np.ndarray:
    """1.4826 MAD of ``r`` over each ``g`` quantile, interpolated in ``g`` at ``at``."""
    edges = np.unique(np.quantile(g, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, g, side="right") - 1, 0, max(0, len(edges) - 2))
    centre, spread = [], []
    for b in range(max(1, len(edges) - 1)):
        if (idx == b).sum() >= 50:
            centre.append(float(np.median(g[idx == b])))
            spread.append(robust_sigma(r[idx == b]))
    return np.interp(at, centre, spread) if centre else np.full(at.shape, robust_sigma(r))


def noise_units(residual: np.ndarray, gain: np.ndarray, bins: int = 8, row_bands: int = 1,
                exclude: np.ndarray | None = None) -> np.ndarray:
    """Step 4: ``residual`` (NaN = invalid) in units of its own noise, measured per class of
    pixels: 1.4826 MAD over each ``gain`` quantile, interpolated in ``gain`` (median = road level).
    ``row_bands`` > 1: measured so within each band of rows (equal pixel counts), interpolated
    linearly between the bands' median rows: a pixel's noise also changes with its range (on the
    loop's tuning highway the fused map's z spread 1.5-2.5 in the farthest sixth of the rows and
    0.8-0.95 in the nearest half; docs/stereo_detector.md), which the predicted gain does not capture.
    ``exclude``: pixels left out of the statistics (still scaled by their class's)."""
    ok = np.isfinite(residual)
    out = np.zeros(residual.shape)
    stats = ok if exclude is None or (ok & ~exclude).sum() < 100 else ok & ~exclude
    if stats.sum() < 100:
        return out
    r, g = residual[stats], gain[stats]
    level = float(np.median(r))
    rows = np.nonzero(stats)[0].astype(np.float64)
    at_rows, at_gain = np.nonzero(ok)[0].astype(np.float64), gain[ok]
    edges = np.unique(np.quantile(rows, np.linspace(0, 1, max(1, row_bands) + 1)))
    band = np.clip(np.searchsorted(edges, rows, side="right") - 1, 0, max(0, len(edges) - 2))
    centres, spreads = [], []
    for b in range(max(1, len(edges) - 1)):
        sel = band == b
        if sel.sum() >= 50 * bins:
            centres.append(float(np.median(rows[sel])))
            spreads.append(_gain_spread(r[sel], g[sel], bins, at_gain))
    if len(centres) < 2:
        spread = _gain_spread(r, g, bins, at_gain)
    else:
        t = np.interp(at_rows, centres, np.arange(len(centres), dtype=np.float64))
        i0 = np.minimum(np.floor(t).astype(int), len(centres) - 2)
        f = t - i0
        stack = np.stack(spreads)
        cols = np.arange(len(at_rows))
        spread = stack[i0, cols] * (1 - f) + stack[i0 + 1, cols] * f
    out[ok] = (residual[ok] - level) / np.maximum(spread, 1e-12)
    return out


def fused_residual(fusion: FrameFusion, ev: PairEvidence | None, z: np.ndarray, valid: np.ndarray, sigma,
                   seg=None, options: FusionOptions | None = None):
    """(z, valid, scale, pairs per pixel) of one pair (its residual ``z`` in units of ``sigma``
    px, its evidence ``ev``) fused with ``fusion``'s pairs: steps 2-4 (and 5), ``z * scale`` in px
    of the pair. Without evidence the pair's own. ``seg``: the detector's segment.SegmentParams
    (step 5's road model); ``options``: :class:`FusionOptions` (default: none of them)."""
    opt = options or FusionOptions()
    residual, gain, count = fusion.fuse(ev, valid)
    if residual is None:
        return z, valid, sigma, count
    valid = np.isfinite(residual)
    zf = noise_units(residual, gain, row_bands=opt.row_bands)
    if opt.exclude_k > 0:      # again without what the first pass calls a defect, or a bump
        far = ndimage.binary_dilation(valid & (np.abs(zf) >= opt.exclude_k), iterations=5)
        zf = noise_units(residual, gain, row_bands=opt.row_bands, exclude=far)
    if opt.refit_road:
        residual, valid, zf = _refit_road(fusion, ev, residual, valid, zf, gain, seg, opt.row_bands)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(valid & (np.abs(zf) > 1e-9), residual / zf, sigma)
    return zf, valid, scale, count


def _refit_road(fusion: FrameFusion, ev: PairEvidence, residual: np.ndarray, valid: np.ndarray, zf: np.ndarray,
                gain: np.ndarray, seg, row_bands: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 5 (residual px, valid, z): each pair's local road model absorbs part of a shallow
    pothole it cannot mask (under its own noise, the pothole never reaches ``mask_k`` or
    ``refit_k``), and fusing absorbed evidence keeps it absorbed. So the depth below each pair's
    road *plane* is fused, and the local road model (road_model.py, the detector's settings
    ``seg``) is fitted on that fused map, masking what the fused map's lower noise shows: the
    regions of step 4's ``zf`` reaching ``mask_k``, then its own rounds and refit."""
    if seg is None:
        raise ValueError("refit_road needs the detector's SegmentParams (seg)")
    raw, _, _ = fusion.fuse(ev, valid, "plane_depth_m")
    if raw is None:
        return residual, valid, zf
    ok = valid & np.isfinite(raw)
    z, _, s = local_road_residual(np.where(ok, raw, 0.0), ok, deep_regions(zf, ok, seg.k_grow, seg.mask_k),
                                  k_grow=seg.k_grow, k_peak=seg.mask_k, tile_frac=seg.tile_frac, blur_px=0.0,
                                  iters=seg.model_iters, refit_k=seg.refit_k, open_px=seg.open_px)
    residual = np.where(ok, z * s, np.nan)
    return residual, ok, noise_units(residual, gain, row_bands=row_bands)


def fused_sequence(frames, prepare, detect, fuse_frames: int, lookahead: int):
    """Per pair of ``frames``, in order, ``detect(state, evidence, others' evidence)`` with the
    evidence of the ``lookahead`` pairs after it and ``fuse_frames - 1 - lookahead`` before it;
    ``prepare(inputs) -> (state, evidence)`` runs once a pair. A pair's result comes once its
    later pairs have arrived (StereoDefects.run_sequence); its state is dropped once detected
    (only its evidence serves the pairs after it)."""
    before = fuse_frames - 1 - lookahead
    window: deque = deque()   # [index, state, evidence] of the pairs still needed
    done = 0

    def emit(k: int):
        entry = next(e for e in window if e[0] == k)
        others = [e[2] for e in window if e[0] != k and k - before <= e[0] <= k + lookahead]
        state, entry[1] = entry[1], None
        return detect(state, entry[2], others)

    for n, inputs in enumerate(frames):
        window.append([n, *prepare(inputs)])
        while done <= n - lookahead:
            yield emit(done)
            done += 1
            while window and window[0][0] < done - before:
                window.popleft()
    while window and done <= window[-1][0]:
        yield emit(done)
        done += 1
