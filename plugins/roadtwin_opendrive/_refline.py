"""Reference-line and profile evaluation (numpy in, numpy out), OpenDRIVE 1.4-1.8 semantics.

Every geometry is evaluated in closed form at any s, not by resampling a polyline:

- line, arc: exact.
- spiral: a general clothoid piece, curvature k(ds) = k0 + c*ds, c = (k1 - k0) / L, any signs, so
  heading = hdg + k0*ds + c*ds^2/2. The position integral is written with Fresnel integrals
  (scipy.special.fresnel) after completing the square around the zero-curvature point. Where
  that is ill-conditioned (a nearly circular spiral: |k0/c| or sqrt(pi/|c|) huge, so Fresnel
  differences cancel) the same integral is done by composite Gauss-Legendre quadrature.
- poly3 (deprecated, still read): v(u) = a + b u + c u^2 + d u^3 in the local (u, v) frame; s is
  arc length along the curve, so u(s) comes from inverting the arc-length integral (tabulated
  with Gauss-Legendre, refined by Newton steps).
- paramPoly3: u(p), v(p) cubics with p = ds (pRange arcLength) or ds / length (normalized), the
  linear s -> p mapping the standard prescribes; heading = hdg + atan2(v', u').
"""
from __future__ import annotations

import numpy as np
from scipy.special import fresnel

from ._xodr import Cubic, Geometry

_GL_X, _GL_W = np.polynomial.legendre.leggauss(10)


def eval_cubics(records: list[Cubic], s: np.ndarray, default: float = 0.0) -> np.ndarray:
    """Piecewise cubic records (each valid from its s to the next record's s) at s."""
    s = np.asarray(s, dtype=np.float64)
    if not records:
        return np.full(s.shape, default)
    starts = np.array([r.s for r in records])
    coef = np.array([[r.a, r.b, r.c, r.d] for r in records])
    i = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(records) - 1)
    ds = s - starts[i]
    a, b, c, d = coef[i].T
    return a + ds * (b + ds * (c + ds * d))


def _line(ds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return ds, np.zeros_like(ds), np.zeros_like(ds)


def _arc(ds: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if abs(k) < 1e-14:
        return _line(ds)
    th = k * ds
    # sin(th)/k and (1-cos(th))/k, written to stay accurate for small th
    return np.sin(th) / k, 2.0 * np.sin(0.5 * th) ** 2 / k, th


def _quad_cumulative(ds: np.ndarray, phase) -> tuple[np.ndarray, np.ndarray]:
    """x(ds), y(ds) = integral_0^ds (cos, sin)(phase(t)) dt by composite 10-point Gauss-Legendre."""
    top = float(np.max(ds)) if len(ds) else 0.0
    grid = np.unique(np.concatenate([[0.0], ds, np.arange(0.0, top, 0.5)]))
    a, b = grid[:-1], grid[1:]
    half = 0.5 * (b - a)
    t = (0.5 * (a + b))[:, None] + half[:, None] * _GL_X[None, :]
    ph = phase(t)
    px = np.concatenate([[0.0], np.cumsum((np.cos(ph) * _GL_W).sum(1) * half)])
    py = np.concatenate([[0.0], np.cumsum((np.sin(ph) * _GL_W).sum(1) * half)])
    idx = np.searchsorted(grid, ds)
    return px[idx], py[idx]


def clothoid(ds: np.ndarray, k0: float, k1: float, length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local x, y, heading of a clothoid piece starting at the origin heading along +x."""
    c = (k1 - k0) / length if length > 0 else 0.0
    if abs(c) < 1e-15:
        return _arc(ds, k0)
    heading = k0 * ds + 0.5 * c * ds * ds
    scale = np.sqrt(np.pi / abs(c))
    u0 = k0 / c
    if scale + abs(u0) > 1e5:  # Fresnel differences would lose more than ~1e-10 m: integrate instead
        x, y = _quad_cumulative(ds, lambda t: k0 * t + 0.5 * c * t * t)
        return x, y, heading
    sign = 1.0 if c > 0 else -1.0
    s1, c1 = fresnel((ds + u0) / scale)
    s0, c0 = fresnel(u0 / scale)
    dx, dy = scale * (c1 - c0), sign * scale * (s1 - s0)
    phi0 = -k0 * k0 / (2.0 * c)  # heading offset after completing the square
    cp, sp = np.cos(phi0), np.sin(phi0)
    return cp * dx - sp * dy, sp * dx + cp * dy, heading


def _poly3(ds: np.ndarray, a: float, b: float, c: float, d: float,
           length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    def dv(u):
        return b + u * (2 * c + 3 * d * u)

    def speed(u):
        return np.sqrt(1.0 + dv(u) ** 2)

    # arc length table A(u) on u in [0, length] (A(u) >= u, so the end lies inside)
    n = max(16, int(np.ceil(length / 0.25)))
    ug = np.linspace(0.0, length, n + 1)
    half = 0.5 * (ug[1:] - ug[:-1])
    mid = 0.5 * (ug[1:] + ug[:-1])
    seg = (speed(mid[:, None] + half[:, None] * _GL_X[None]) * _GL_W).sum(1) * half
    ag = np.concatenate([[0.0], np.cumsum(seg)])
    u = np.interp(ds, ag, ug)
    for _ in range(4):  # Newton on A(u) - ds = 0
        i = np.clip(np.searchsorted(ug, u, side="right") - 1, 0, n - 1)
        h = 0.5 * (u - ug[i])
        partial = (speed(ug[i][:, None] + h[:, None] * (1 + _GL_X[None])) * _GL_W).sum(1) * h
        u = u - (ag[i] + partial - ds) / speed(u)
    v = a + u * (b + u * (c + u * d))
    return u, v, np.arctan(dv(u))


def _param_poly3(ds: np.ndarray, p: dict, length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = ds if p["pRange"] == "arcLength" else ds / length
    u = p["aU"] + t * (p["bU"] + t * (p["cU"] + t * p["dU"]))
    v = p["aV"] + t * (p["bV"] + t * (p["cV"] + t * p["dV"]))
    du = p["bU"] + t * (2 * p["cU"] + 3 * p["dU"] * t)
    dv = p["bV"] + t * (2 * p["cV"] + 3 * p["dV"] * t)
    return u, v, np.arctan2(dv, du)


def local_xy(g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position and heading relative to the geometry's start frame."""
    p = g.params
    if g.kind == "line":
        return _line(ds)
    if g.kind == "arc":
        return _arc(ds, p["curvature"])
    if g.kind == "spiral":
        return clothoid(ds, p["curvStart"], p["curvEnd"], g.length)
    if g.kind == "poly3":
        return _poly3(ds, p["a"], p["b"], p["c"], p["d"], g.length)
    if g.kind == "paramPoly3":
        return _param_poly3(ds, p, g.length)
    raise ValueError(g.kind)  # the parser refuses unknown kinds


def geometry_xyh(g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World x, y, heading of one geometry at ds from its start."""
    ds = np.asarray(ds, dtype=np.float64)
    u, v, h = local_xy(g, ds)
    ch, sh = np.cos(g.hdg), np.sin(g.hdg)
    return g.x + ch * u - sh * v, g.y + sh * u + ch * v, g.hdg + h


class ReferenceLine:
    """A road's planView: x, y, heading at any s (s past the end extrapolates the last piece)."""

    def __init__(self, geometries: list[Geometry]) -> None:
        self.geometries = geometries
        self.starts = np.array([g.s for g in geometries])

    def boundaries(self) -> np.ndarray:
        return self.starts[1:]

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = np.asarray(s, dtype=np.float64)
        idx = np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.geometries) - 1)
        x, y, h = np.empty_like(s), np.empty_like(s), np.empty_like(s)
        for i in np.unique(idx):
            m = idx == i
            g = self.geometries[i]
            x[m], y[m], h[m] = geometry_xyh(g, np.maximum(s[m] - g.s, 0.0))
        return x, y, h

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Signed curvature (for lines, arcs and spirals; poly3/paramPoly3 numerically)."""
        s = np.asarray(s, dtype=np.float64)
        idx = np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.geometries) - 1)
        k = np.zeros_like(s)
        for i in np.unique(idx):
            m = idx == i
            g = self.geometries[i]
            ds = s[m] - g.s
            if g.kind == "arc":
                k[m] = g.params["curvature"]
            elif g.kind == "spiral":
                k[m] = g.params["curvStart"] + (g.params["curvEnd"] - g.params["curvStart"]) * ds / g.length
            elif g.kind != "line":
                eps = 1e-4
                k[m] = (geometry_xyh(g, ds + eps)[2] - geometry_xyh(g, np.maximum(ds - eps, 0))[2]) / (
                    ds + eps - np.maximum(ds - eps, 0))
        return k
