"""A square crop of road -> a tile that repeats without a seam, its roughness and normal maps,
and the measure of a seam (core-free: numpy, scipy.ndimage).

**Seamless by wrap blending.** The crop is ``n + m`` texels a side for an ``n``-texel tile: the
``m`` texels that follow the tile's right (bottom) edge in the photo are cross-faded into its
first ``m`` columns (rows), so across the wrap the tile's last column is followed by what
followed it on the road, and the blend hands over to the tile's own content within ``m``
texels. Nothing is mirrored or offset, so no feature is doubled. The cross-fade is
*variance-preserving* (the blend of the deviations from the mean is divided by
``sqrt(w^2 + (1 - w)^2)``, Heitz & Neyret 2018, "High-performance by-example noise using a
histogram-preserving blending operator"): a plain average of two unrelated patches of asphalt
is visibly smoother and greyer than either, and that band would repeat with the tile. A linear
ramp of light across the crop (exposure, vignetting, a gentle shadow edge) is removed first,
since it would come back as a step at every repeat.

**The seam measure** (:func:`seam_ratio`): the mean absolute luminance difference between the
tile's last and first column (row), which the repeat puts side by side, over the mean absolute
difference between neighbouring columns (rows) just inside the last one. About 1 means the seam cannot be told
from any other column pair; an unblended crop of a photo measures several.

**Roughness and normal** as :mod:`.patch` derives them from colour (rougher where the
high-pass luminance varies more; a height field of the high-pass luminance, darker = lower,
1.5 cm per unit of contrast), with every filter wrapping around, so they repeat seamlessly too.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

ROUGHNESS_BASE = 0.8
HEIGHT_PER_CONTRAST_M = 0.015
LUMA = np.array([0.299, 0.587, 0.114])
REC709 = np.array([0.2126, 0.7152, 0.0722])       # luminance of linear light (Rec. 709 primaries)


def srgb_to_linear(c8: np.ndarray) -> np.ndarray:
    c = np.asarray(c8, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)       # IEC 61966-2-1


def linear_to_srgb8(lin: np.ndarray) -> np.ndarray:
    lin = np.clip(lin, 0.0, 1.0)
    c = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055)
    return (c * 255 + 0.5).astype(np.uint8)


def linear_luminance(srgb8: np.ndarray) -> float:
    """Mean linear (Rec. 709) luminance of an sRGB image."""
    return float((srgb_to_linear(srgb8) @ REC709).mean())


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., :3].astype(np.float64) @ LUMA


def remove_light_ramp(crop: np.ndarray) -> np.ndarray:
    """Per channel, subtract the least-squares plane through the crop (its mean kept)."""
    h, w = crop.shape[:2]
    rr, cc = np.mgrid[0:h, 0:w]
    basis = np.column_stack([np.ones(h * w), (rr.ravel() - h / 2) / h, (cc.ravel() - w / 2) / w])
    values = crop.reshape(h * w, -1).astype(np.float64)
    coef, *_ = np.linalg.lstsq(basis, values, rcond=None)
    coef[0] = 0.0
    return (values - basis @ coef).reshape(crop.shape)


def _blend_wrap(a: np.ndarray, n: int, m: int, mean: np.ndarray) -> np.ndarray:
    """Along axis 1: (rows, n + m, C) -> (rows, n, C), the last m columns cross-faded into the first."""
    t = (np.arange(m) + 0.5) / m
    w = (t * t * (3 - 2 * t))[None, :, None]                # weight of the tile's own columns
    own, follow = a[:, :m] - mean, a[:, n:n + m] - mean
    mixed = (w * own + (1 - w) * follow) / np.sqrt(w * w + (1 - w) ** 2)
    out = a[:, :n].copy()
    out[:, :m] = mean + mixed
    return out


def make_seamless(crop: np.ndarray, n: int) -> np.ndarray:
    """``crop`` (n + m, n + m, C) float or uint8 -> (n, n, C) float64 tile that wraps
    seamlessly both ways (module docstring); ``m`` >= 2."""
    side = crop.shape[0]
    m = side - n
    if crop.shape[1] != side or m < 2:
        raise ValueError(f"make_seamless: crop {crop.shape[:2]} must be square and at least {n + 2} a side")
    a = remove_light_ramp(crop)
    mean = a.reshape(-1, a.shape[-1]).mean(axis=0)
    a = _blend_wrap(a, n, m, mean)                          # columns
    a = _blend_wrap(a.transpose(1, 0, 2), n, m, mean)       # rows
    return a.transpose(1, 0, 2)


def seam_ratio(tile: np.ndarray, band: int | None = None) -> dict[str, float]:
    """Seam / interior mean absolute luminance difference, across columns and rows. The
    interior reference is the ``band`` neighbouring pairs just before the seam (default: a
    tenth of the tile), the same stretch of road the seam's last column belongs to: a photo's
    sharpness changes with range, so a whole-tile average would flatter or blame the seam."""
    lum = luminance(tile) if tile.ndim == 3 else tile.astype(np.float64)
    out = {}
    for axis, key in ((1, "columns"), (0, "rows")):
        n = lum.shape[axis]
        k = band or max(2, n // 10)
        inner = np.abs(np.diff(np.take(lum, range(n - k - 1, n), axis=axis), axis=axis)).mean()
        seam = np.abs(np.take(lum, 0, axis=axis) - np.take(lum, -1, axis=axis)).mean()
        out[key] = float(seam / max(inner, 1e-12))
    return out


def period_correlation(tile: np.ndarray, lag: int) -> dict[str, float]:
    """The luminance's normalised circular autocorrelation at ``lag`` texels along the columns
    (s, along travel) and the rows (t): the tile repeats, so this is the correlation of the
    road with itself ``lag`` texels on over any stretch of it. 1 where a ``lag``-texel window
    is repeated; an aperiodic texture of the same grain measures near 0 (its coarse blotches
    aside). Wiener-Khinchin: the inverse FFT of the power spectrum."""
    lum = luminance(tile) if tile.ndim == 3 else tile.astype(np.float64)
    lum = lum - lum.mean()
    power = np.abs(np.fft.rfft2(lum)) ** 2
    auto = np.fft.irfft2(power, s=lum.shape)
    auto /= max(float(auto[0, 0]), 1e-12)
    return {"columns": float(auto[0, lag % lum.shape[1]]), "rows": float(auto[lag % lum.shape[0], 0])}


def derived_maps(tile_rgb: np.ndarray, texel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(roughness (n, n) in 0..1, unit normal (n, n, 3) in tangent space: x along columns
    (s), y up the rows (t), z out) of a periodic tile, as :mod:`.patch` derives them."""
    lum = luminance(tile_rgb) / 255.0
    sigma = max(1.0, 0.02 / texel_m)
    high = lum - gaussian_filter(lum, sigma, mode="wrap")
    local_std = np.sqrt(np.maximum(gaussian_filter(high * high, sigma, mode="wrap"), 0.0))
    ref = float(np.median(local_std)) + 1e-6
    roughness = np.clip(ROUGHNESS_BASE + 0.1 * np.tanh(local_std / ref - 1), 0.05, 1.0)
    height = high * HEIGHT_PER_CONTRAST_M / texel_m          # in texels
    g_rows = 0.5 * (np.roll(height, -1, 0) - np.roll(height, 1, 0))
    g_cols = 0.5 * (np.roll(height, -1, 1) - np.roll(height, 1, 1))
    normal = np.stack([-g_cols, g_rows, np.ones_like(height)], axis=-1)
    return roughness, normal / np.linalg.norm(normal, axis=-1, keepdims=True)


def encode_normal(normal: np.ndarray) -> np.ndarray:
    return ((normal * 0.5 + 0.5) * 255 + 0.5).astype(np.uint8)
