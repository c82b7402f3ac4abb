"""What a material generator returns: per-texel fields over one tile, before encoding."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .catalog import ST_TILE_M


@dataclass
class Surface:
    """Fields over one ``ST_TILE_M`` tile, rows along v (row 0 at v = 0), columns along u.

    ``albedo``: linear RGB in [0, 1]; ``roughness``: linear, a field or a constant; ``height``:
    metres (``None``: flat, no normal map); ``normal_strength`` exaggerates its slopes.
    """

    albedo: np.ndarray
    roughness: np.ndarray | float
    height: np.ndarray | None = None
    normal_strength: float = 1.0
    metallic: float = 0.0


def grid_m(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre coordinates ``(u, v)`` in metres, each ``(n, n)`` (rows = v)."""
    c = (np.arange(n, dtype=np.float32) + 0.5) * (ST_TILE_M / n)
    v, u = np.meshgrid(c, c, indexing="ij")
    return u, v


def rgb(*values: float) -> np.ndarray:
    return np.asarray(values, dtype=np.float32)


def srgb(r: int, g: int, b: int) -> np.ndarray:
    """An sRGB 8-bit colour as linear RGB (colours are easier to pick in sRGB)."""
    x = np.asarray([r, g, b], dtype=np.float32) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)
