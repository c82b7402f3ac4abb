"""Linear radiance -> 8-bit sRGB, the one tone curve every image of a render goes through
(writers, sensor model, previews)."""
from __future__ import annotations

import numpy as np

__all__ = ["to_srgb8"]


def to_srgb8(rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance -> 8-bit sRGB: exponential tone curve, then the sRGB transfer function."""
    x = 1.0 - np.exp(-np.maximum(np.asarray(rgb, dtype=np.float32), 0.0) * exposure)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.clip(np.rint(s * 255.0), 0, 255).astype(np.uint8)
