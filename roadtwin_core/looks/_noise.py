"""Periodic building blocks for the texture generators: everything here tiles by construction.

Why FFT: noise synthesised from a spectrum that holds only whole cycles per tile is exactly
periodic, so a texture repeats without a seam; stamps and gradients below likewise wrap
around the tile edges. Fields are ``(n, n)`` arrays over one ``ST_TILE_M`` tile with rows along v
and columns along u (row 0 at v = 0; the writer flips rows into image order).
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from .catalog import ST_TILE_M


def spectral_noise(rng: np.random.Generator, n: int, lam_min: float, lam_max: float = ST_TILE_M,
                   slope: float = 1.0, stretch_u: float = 1.0) -> np.ndarray:
    """Zero-mean, unit-std periodic noise with wavelengths ~``lam_min``..``lam_max`` metres.

    Amplitude falls as ``f^-slope`` (1: natural-looking "pink" mottling, 0: white speckle) with
    smooth Gaussian roll-offs at both ends (no ringing). ``stretch_u`` > 1 elongates features
    along u by that factor (streaks along travel), < 1 across it.
    """
    f32 = np.float32
    fv = np.fft.fftfreq(n, 1.0 / n).astype(f32)[:, None]  # cycles per tile along v (rows)
    fu = np.fft.rfftfreq(n, 1.0 / n).astype(f32)[None, :]
    f2 = fv * fv + (fu * f32(stretch_u)) ** 2
    f2[0, 0] = 1.0
    f_hi, f_lo = ST_TILE_M / lam_min, ST_TILE_M / lam_max
    amp = f2 ** f32(-slope / 2) * np.exp(-f2 / f32(f_hi * f_hi)) * -np.expm1(-f2 / f32(f_lo * f_lo))
    amp[0, 0] = 0.0
    shape = amp.shape
    spec = np.empty(shape, np.complex64)
    spec.real = rng.standard_normal(shape, dtype=f32) * amp
    spec.imag = rng.standard_normal(shape, dtype=f32) * amp
    x = scipy.fft.irfft2(spec, s=(n, n), workers=1)
    return (x * f32(1.0 / max(float(x.std()), 1e-12))).astype(f32)


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def stamp_stones(rng: np.random.Generator, n: int, count: int, r_lo: float, r_hi: float,
                 aspect: float = 1.6, values: np.ndarray | None = None):
    """Splat ``count`` elliptic stones (radii ``r_lo..r_hi`` m, random axis ratio up to ``aspect``
    and orientation) into an ``(n, n)`` tile, wrapping around its edges.

    Returns ``(cover, dome, value)``: anti-aliased coverage in [0, 1], a dome profile (1 at a
    stone's centre, 0 at its rim; where stones overlap they average) and the coverage-weighted
    mean of the per-stone ``values`` (``(count,)`` or ``(count, c)``; default: uniform 0..1).
    """
    px = ST_TILE_M / n
    if values is None:
        values = rng.random(count)
    values = np.asarray(values, dtype=np.float64).reshape(count, -1)
    cy, cx = rng.random(count) * n, rng.random(count) * n
    a = rng.uniform(r_lo, r_hi, count) / px  # semi-axes in pixels
    b = a / rng.uniform(1.0, aspect, count)
    ang = rng.uniform(0.0, np.pi, count)
    r_px = int(np.ceil(a.max() + 1.0))  # rim + anti-aliasing + sub-pixel centre
    # Each stone is tested over its own window, not the largest stone's: the anti-aliased rim
    # reaches a * (1 + 0.5 / b) px from the centre, +1 for the sub-pixel centre (capped at the
    # common window, so the pixels kept are exactly those of one window for all).
    r_own = np.minimum(np.ceil(a * (1.0 + 0.5 / b) + 1.0), r_px).astype(np.int64)
    iy, ix = np.floor(cy).astype(np.int64), np.floor(cx).astype(np.int64)
    f32 = np.float32
    idx_parts, w_parts, dome_parts, stone_parts = [], [], [], []
    for r in np.unique(r_own):
        sel = np.flatnonzero(r_own == r)
        off = np.arange(-r, r + 1)
        dy, dx = [o.ravel() for o in np.meshgrid(off, off, indexing="ij")]
        py = (iy[sel] + 0.5 - cy[sel]).astype(f32)[:, None] + dy.astype(f32)  # pixel centre relative to the stone
        pxx = (ix[sel] + 0.5 - cx[sel]).astype(f32)[:, None] + dx.astype(f32)
        c, s = np.cos(ang[sel]).astype(f32)[:, None], np.sin(ang[sel]).astype(f32)[:, None]
        lu, lv = (c * pxx + s * py) / a[sel].astype(f32)[:, None], (-s * pxx + c * py) / b[sel].astype(f32)[:, None]
        rho2 = lu * lu + lv * lv  # 1 on the rim
        b32 = b[sel].astype(f32)[:, None]
        keep = rho2 < (1.0 + 0.5 / b32) ** 2  # inside the anti-aliased edge
        rho = np.sqrt(rho2[keep])
        w_parts.append(np.clip((1.0 - rho) * np.broadcast_to(b32, keep.shape)[keep] + 0.5, 0.0, 1.0))  # ~1 px AA
        dome_parts.append(np.sqrt(np.clip(1.0 - rho * rho, 0.0, 1.0)))
        local, k = np.nonzero(keep)
        stone = sel[local]
        idx_parts.append(((iy[stone] + dy[k]) % n) * n + (ix[stone] + dx[k]) % n)
        stone_parts.append(stone)
    idx, w, dome = np.concatenate(idx_parts), np.concatenate(w_parts), np.concatenate(dome_parts)
    stone = np.concatenate(stone_parts)
    cov = np.bincount(idx, w, minlength=n * n)
    safe = np.maximum(cov, 1e-9)
    dome_out = np.bincount(idx, w * dome, minlength=n * n) / safe
    val = np.stack([np.bincount(idx, w * values[stone, j], minlength=n * n) / safe
                    for j in range(values.shape[1])], axis=-1)
    shape = (n, n)
    return (np.minimum(cov, 1.0).reshape(shape).astype(np.float32), dome_out.reshape(shape).astype(np.float32),
            val.reshape(shape + (values.shape[1],)).squeeze(-1).astype(np.float32) if values.shape[1] == 1
            else val.reshape(shape + (values.shape[1],)).astype(np.float32))


def block_mean(field: np.ndarray, factor: int) -> np.ndarray:
    """Downsample by averaging ``factor x factor`` blocks (keeps periodicity)."""
    if factor == 1:
        return field
    n = field.shape[0] // factor
    return field[: n * factor, : n * factor].reshape(n, factor, n, factor, *field.shape[2:]).mean(axis=(1, 3))


def normal_map(height_m: np.ndarray, strength: float = 1.0) -> np.ndarray:
    """Tangent-space unit normals ``(n, n, 3)`` of a periodic height field (metres, rows = v).

    x along u, y along v, z out of the surface; ``strength`` exaggerates slopes (a real 1 mm
    macrotexture barely tilts a 4 mm texel, but shading should still show the aggregate).
    """
    n = height_m.shape[0]
    px = ST_TILE_M / n
    hu = (np.roll(height_m, -1, axis=1) - np.roll(height_m, 1, axis=1)) / (2 * px)
    hv = (np.roll(height_m, -1, axis=0) - np.roll(height_m, 1, axis=0)) / (2 * px)
    nrm = np.stack([-strength * hu, -strength * hv, np.ones_like(hu)], axis=-1)
    return nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)


def _srgb_lut(levels: int = 16384) -> np.ndarray:
    x = np.arange(levels) / (levels - 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


_SRGB = _srgb_lut()


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB 8-bit through a fine lookup table (exact to < 0.5 level, fast)."""
    idx = np.round(np.clip(rgb, 0.0, 1.0) * (len(_SRGB) - 1)).astype(np.int32)
    return _SRGB[idx]


def unit_to_u8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
