"""Fan et al.'s disparity transformation (IEEE T-IP 2019) and SGBM disparity (core-free).

A flat road seen by a rectified stereo camera has a disparity that is linear in (u, v): with the
road plane ``n . P = -H`` in camera coordinates (X right, Y down, Z forward), the depth of pixel
(u, v) is ``Z = -H / (n . ((u-cx)/f, (v-cy)/f, 1))`` and ``d = f B / Z`` is affine in u and v. With
a camera roll the iso-disparity lines are the image rows rotated by the roll angle theta, so
along the rotated row coordinate ``v' = u sin(theta) + v cos(theta)`` the road disparity is a
1-D function ``f(v')`` (quadratic, to allow a gently curved road). Fan et al. estimate theta by
minimising the fitting energy ``E(theta) = min_f sum (d - f(v'))^2`` over a 1-D search, then
transform ``d'(u, v) = d(u, v) - f(v') + delta``: the road becomes constant ``delta`` and a
pothole (farther, so lower disparity) stands out below it.

Here: coarse grid over theta (0.5 deg), bounded scalar refinement, and the fit is made robust by
iterated trimming (pixels beyond 3 robust sigma, i.e. potholes and mismatches, are refitted
without), alternating with the theta search once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RoadDisparityModel:
    theta: float              # roll angle (rad): iso-disparity lines are rows rotated by theta
    coef: np.ndarray          # quadratic f(v') = c0 + c1 v' + c2 v'^2 (np.polyval order reversed)
    delta: float              # constant the road maps to
    sigma: float              # robust residual spread of the road pixels

    def road(self, shape: tuple[int, int]) -> np.ndarray:
        h, w = shape
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        t = u * np.sin(self.theta) + v * np.cos(self.theta)
        return self.coef[0] + self.coef[1] * t + self.coef[2] * t * t


def _fit(t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.stack([np.ones_like(t), t, t * t], axis=-1)
    c, *_ = np.linalg.lstsq(a, d, rcond=None)
    return c, d - a @ c


def _energy(theta: float, u: np.ndarray, v: np.ndarray, d: np.ndarray) -> float:
    t = (u * np.sin(theta) + v * np.cos(theta)) / 1000.0
    _, r = _fit(t, d)
    return float(np.mean(r * r))


def fit_road_disparity(disp: np.ndarray, theta_range_deg: float = 45.0, step: int = 4,
                       max_points: int = 60000) -> RoadDisparityModel:
    """Estimate the roll angle and the road disparity model f(v') of a raw disparity map
    (NaN or <= 0 = invalid)."""
    from scipy.optimize import minimize_scalar

    d = np.asarray(disp, dtype=np.float64)
    h, w = d.shape
    vv, uu = np.mgrid[0:h:step, 0:w:step]
    z = d[::step, ::step]
    ok = np.isfinite(z) & (z > 0)
    if ok.sum() < 50:
        raise ValueError("too few valid disparities to fit a road model")
    u, v, z = uu[ok].astype(np.float64), vv[ok].astype(np.float64), z[ok]
    if len(z) > max_points:
        idx = np.random.default_rng(0).choice(len(z), max_points, replace=False)
        u, v, z = u[idx], v[idx], z[idx]
    inl = np.ones(len(z), bool)
    lim = np.radians(theta_range_deg)
    theta = 0.0
    for _round in range(2):
        grid = np.arange(-lim, lim + 1e-9, np.radians(0.5))
        e = [_energy(t, u[inl], v[inl], z[inl]) for t in grid]
        i = int(np.argmin(e))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        theta = float(minimize_scalar(_energy, bounds=(lo, hi), args=(u[inl], v[inl], z[inl]),
                                      method="bounded", options={"xatol": 1e-6}).x)
        tt = (u * np.sin(theta) + v * np.cos(theta)) / 1000.0
        for _ in range(8):  # iterated 3-sigma trimming at this theta
            c, _ = _fit(tt[inl], z[inl])
            r = z - (c[0] + c[1] * tt + c[2] * tt * tt)
            s = 1.4826 * np.median(np.abs(r[inl] - np.median(r[inl]))) + 1e-12
            new = np.abs(r) < 3 * s
            if np.array_equal(new, inl) or new.sum() < 20:
                break
            inl = new
    c, r = _fit(tt[inl], z[inl])
    s = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    coef = np.array([c[0], c[1] / 1000.0, c[2] / 1e6])
    delta = float(np.percentile(z[inl], 99)) + 1.0
    return RoadDisparityModel(theta, coef, delta, s)


def transform_disparity(disp: np.ndarray, model: RoadDisparityModel | None = None) -> tuple[np.ndarray, RoadDisparityModel]:
    """``d' = d - f(v') + delta`` (NaN stays NaN); returns the map and the fitted model."""
    d = np.asarray(disp, dtype=np.float64).copy()
    d[~np.isfinite(d) | (d <= 0)] = np.nan
    model = model or fit_road_disparity(d)
    return d - model.road(d.shape) + model.delta, model


def sgbm_disparity(left: np.ndarray, right: np.ndarray, max_disparity: int = 128, block: int = 5) -> np.ndarray:
    """OpenCV semi-global block matching on a rectified pair; float disparity, NaN = invalid."""
    import cv2

    if left.shape[:2] != right.shape[:2]:
        raise ValueError(f"left and right images differ in size: {left.shape[:2]} vs {right.shape[:2]}")
    gl = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY) if left.ndim == 3 else left
    gr = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY) if right.ndim == 3 else right
    nd = int(np.ceil(max_disparity / 16.0) * 16)
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=block,
                              P1=8 * block * block, P2=32 * block * block, uniquenessRatio=5,
                              speckleWindowSize=100, speckleRange=2, disp12MaxDiff=1,
                              mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    d = m.compute(gl, gr).astype(np.float64) / 16.0
    d[d <= 0] = np.nan
    return d
