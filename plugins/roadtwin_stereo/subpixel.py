"""Sub-pixel refinement of a block-matching disparity map (core-free: numpy + OpenCV).

Why: SGBM's sub-pixel step (a parabola through three integer costs) is biased towards whole
pixels ("pixel locking", Shimizu & Okutomi 2001): on a road seen 5-10 m ahead with a 12 cm
baseline a 10 cm pothole is a 0.2-0.6 px disparity dip, which SGBM returns as a flat integer
plateau. The classic remedy is a continuous refinement of the match around SGBM's answer:
windowed Lucas-Kanade along the rectified rows (Lucas & Kanade 1981; its stereo form in e.g.
Psarakis & Evangelidis 2005 / Nehab et al. 2005 "Improved sub-pixel stereo correspondences
through symmetric refinement"), which has no integer grid and so no locking.

Model, per pixel x and a Gaussian window W around it (rows are epipolar lines):
``I_L(x) = I_R(x - d - delta) + b``. With ``w = I_R(x - d)`` (bicubic warp) and
``r = I_L - w ~ -g delta + b``, the least-squares ``delta`` over W, with a free brightness
offset ``b``, is ``-cov_W(g, r) / var_W(g)`` (the 2x2 normal equations, solved in closed form);
``g`` is the symmetric gradient ``(dI_L/dx + dw/dx) / 2`` (Nehab et al.'s symmetric form, which
halves the linearisation bias). A few Gauss-Newton steps; SGBM's value is kept where the window
has no texture or where the refinement leaves a +-``max_shift`` px band around SGBM.

Trust (issue 20, item 5): the fit also says how good each match is. Its residual RMS
``res = sqrt(var(r) - cov(g, r)^2 / var(g))`` (grey levels left unexplained by a shift) and its
predicted standard error ``res / sqrt(var(g))`` (up to the window's constant pixel count). Where
the two views disagree (view-dependent appearance, an edge the window straddles, low texture)
the refinement lands 0.2-0.8 px off, in compact patches a pothole detector takes for dips (the
loop's false detections, docs/stereo_detector.md). Pixels whose standard error exceeds
``reject[0]`` x the frame's median, or whose residual exceeds ``reject[1]`` x its median, are
returned invalid (NaN): the ratios are to the frame's own figures, so no grey-level or pixel
constant enters. ``reject=None`` keeps every refined value.
"""
from __future__ import annotations

import numpy as np


def _gray32(img: np.ndarray) -> np.ndarray:
    import cv2

    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
    return np.asarray(g, np.float32)


def _dx(img: np.ndarray) -> np.ndarray:
    """Central difference along the rows (d/du), one-sided at the image edges."""
    return np.gradient(img, axis=1).astype(np.float32)


def _blur(x: np.ndarray, sigma: tuple[float, float]) -> np.ndarray:
    """Gaussian window (sigma along u, sigma along v)."""
    import cv2

    return cv2.GaussianBlur(x, (0, 0), sigmaX=sigma[0], sigmaY=sigma[1], borderType=cv2.BORDER_REPLICATE)


def _weighted_mean(x: np.ndarray, w: np.ndarray, wsum: np.ndarray, sigma: tuple[float, float]) -> np.ndarray:
    return _blur(x * w, sigma) / wsum


def refine_disparity(left: np.ndarray, right: np.ndarray, disp: np.ndarray,
                     window_sigma: float | tuple[float, float] = (6.0, 2.0),
                     iters: int = 5, max_shift: float = 1.0, min_texture: float = 1.0,
                     reject: tuple[float, float] | None = None) -> np.ndarray:
    """Refined float64 disparity (NaN where ``disp`` is NaN or <= 0). ``left``/``right`` are the
    rectified pair ``disp`` was computed on (gray or BGR, same size); ``window_sigma`` (px) is the
    Gaussian matching window, one number or (along u, along v): a road seen at a grazing angle is
    foreshortened along v, so a window narrower along v keeps more of a pothole's profile; ``min_texture`` the least RMS gradient (grey levels / px) in the
    window for a refinement to be trusted; ``reject`` (standard-error ratio, residual ratio): the
    matches returned invalid (module docstring)."""
    import cv2

    sigma = (float(window_sigma), float(window_sigma)) if np.isscalar(window_sigma) else tuple(map(float, window_sigma))
    gl, gr = _gray32(left), _gray32(right)
    if gl.shape != gr.shape or gl.shape != np.shape(disp):
        raise ValueError(f"left {gl.shape}, right {gr.shape} and disparity {np.shape(disp)} differ in size")
    d0 = np.asarray(disp, np.float64)
    valid = np.isfinite(d0) & (d0 > 0)
    if not valid.any():
        return np.where(valid, d0, np.nan)
    h, w = gl.shape
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    wv = valid.astype(np.float32)
    gxl = _dx(gl)
    d = np.where(valid, d0, 0.0).astype(np.float32)
    ok = valid.copy()
    for _ in range(iters):
        warped = cv2.remap(gr, uu - d, vv, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        inside = (uu - d >= 1) & (uu - d <= w - 2)
        g = 0.5 * (gxl + _dx(warped))
        r = gl - warped
        wt = wv * inside
        wsum = _blur(wt, sigma) + 1e-6
        mg, mr = _weighted_mean(g, wt, wsum, sigma), _weighted_mean(r, wt, wsum, sigma)
        var_g = _weighted_mean(g * g, wt, wsum, sigma) - mg * mg
        cov = _weighted_mean(g * r, wt, wsum, sigma) - mg * mr
        var_r = _weighted_mean(r * r, wt, wsum, sigma) - mr * mr
        textured = var_g > min_texture ** 2
        step = np.where(textured, -cov / np.maximum(var_g, 1e-12), 0.0)
        # the window's mean disparity plus the step: a per-pixel update would keep (and add up)
        # the noise of the neighbours' warps, which the window cannot see
        base = _weighted_mean(d, wt, wsum, sigma)
        d = np.where(ok, base + np.clip(step, -0.5, 0.5), d).astype(np.float32)
        ok &= textured & inside
    refined = d.astype(np.float64)
    keep = ok & (np.abs(refined - d0) <= max_shift)
    out = np.where(keep, refined, d0)
    out[~valid] = np.nan
    if reject is not None and keep.any():
        res = np.sqrt(np.maximum(var_r - cov * cov / np.maximum(var_g, 1e-12), 0.0))
        err = res / np.sqrt(np.maximum(var_g, 1e-12))
        bad = (err > reject[0] * np.median(err[keep])) | (res > reject[1] * np.median(res[keep]))
        out[keep & bad] = np.nan
    return out
