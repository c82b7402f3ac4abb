"""Thin finishes and metal: road paint (white, yellow) and the cast-iron manhole cover."""
from __future__ import annotations

import numpy as np

from ._noise import smoothstep, spectral_noise, stamp_stones
from ._surface import Surface, grid_m, srgb
from .catalog import ST_TILE_M


def _paint(rng: np.random.Generator, n: int, colour: np.ndarray) -> Surface:
    """Slightly worn thermoplastic/paint: the coat follows the asphalt's aggregate (its tops wear
    through first as dark specks), blotchy wear patches, glass-bead sheen (lower roughness)."""
    px = ST_TILE_M / n
    _, dome, _ = stamp_stones(rng, n, int(2500 * ST_TILE_M ** 2), 0.002, 0.006)
    cover, _, _ = stamp_stones(rng, n, int(120 * ST_TILE_M ** 2), 0.002, 0.005)  # worn-through tips
    wear = smoothstep(1.3, 2.0, spectral_noise(rng, n, 0.012, 0.3, slope=0.8))
    grain = spectral_noise(rng, n, 1.8 * px, 0.02, slope=0.2)
    dirt = spectral_noise(rng, n, 0.1, ST_TILE_M, slope=1.2)
    through = np.clip(np.maximum(0.8 * cover, 0.75 * wear), 0, 1)
    paint = colour[None, None, :] * (1.0 + 0.04 * grain - 0.05 * dirt)[..., None]
    asphalt = srgb(70, 70, 70)[None, None, :]
    albedo = paint * (1 - through[..., None]) + asphalt * through[..., None]
    height = 0.0008 * dome
    rough = 0.5 + 0.35 * through + 0.03 * grain
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.5)


def paint_white(rng: np.random.Generator, n: int) -> Surface:
    return _paint(rng, n, srgb(232, 232, 226))


def paint_yellow(rng: np.random.Generator, n: int) -> Surface:
    return _paint(rng, n, srgb(226, 172, 36))


def cast_iron(rng: np.random.Generator, n: int) -> Surface:
    """Manhole cover: dark cast iron with a raised diamond-stud tread (6.25 cm pitch), the stud
    tops polished bright by tires, rust and dirt in the recesses."""
    px = ST_TILE_M / n
    pitch = ST_TILE_M / 64
    u, v = grid_m(n)
    a, b = u / pitch, v / pitch
    # Staggered diamonds: L1 distance to the nearest lattice point of a 45-degree rotated grid.
    da = np.abs(np.mod(a + 0.5, 1.0) - 0.5)
    db = np.abs(np.mod(b + 0.5, 1.0) - 0.5)
    d1 = np.minimum(da + db, (0.5 - da) + (0.5 - db))  # distance in pitch units (L1)
    edge = (0.30 - d1) * pitch * np.sqrt(0.5)  # metres inside the diamond's edge
    stud = smoothstep(-0.6 * px, 0.6 * px, edge)
    top = smoothstep(0.0, 0.004, edge)
    rust = smoothstep(0.2, 1.4, spectral_noise(rng, n, 0.01, 0.5, slope=1.0)) * (1.0 - 0.8 * top)
    grain = spectral_noise(rng, n, 1.8 * px, 0.02, slope=0.2)
    metal = srgb(58, 58, 60)[None, None, :] * (1.0 + 0.06 * grain)[..., None]
    polished = srgb(112, 112, 116)[None, None, :]
    rusty = srgb(96, 52, 28)[None, None, :] * (1.0 + 0.2 * grain)[..., None]
    albedo = metal * (1 - top[..., None]) + polished * top[..., None]
    albedo = albedo * (1 - rust[..., None]) + rusty * rust[..., None]
    height = 0.003 * stud
    rough = 0.62 - 0.30 * top + 0.30 * rust + 0.03 * grain
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32),
                   normal_strength=1.0, metallic=0.5)
