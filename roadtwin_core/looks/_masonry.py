"""Laid surfaces: cobblestone setts, sidewalk pavers, concrete slabs.

Why one layout helper: all three are rows of rectangular units separated by joints. A running
bond with a whole number of rows and units per tile (per-row widths renormalised to the tile)
is periodic, and the distance to the unit's rounded-rectangle edge (metres) drives everything:
anti-aliased joints, domed or chamfered tops, dirt collecting near the edges.
"""
from __future__ import annotations

import numpy as np

from ._noise import smoothstep, spectral_noise
from ._surface import Surface, grid_m, srgb
from .catalog import ST_TILE_M


def bond_layout(rng: np.random.Generator, n: int, rows: int, per_row: int, *, width_jitter: float = 0.0,
                shift: str = "half", warp_m: float = 0.0, corner_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per texel: unit id ``(n, n)`` and inner distance to the unit's edge in metres.

    ``shift``: "half" (classic running bond), "random" (each row offset at random) or "none"
    (stacked). ``warp_m`` displaces the layout with smooth periodic noise (hand-laid stones).
    """
    u, v = grid_m(n)
    if warp_m > 0:
        u = u + warp_m * spectral_noise(rng, n, 0.04, 0.5, slope=1.0)
        v = v + warp_m * spectral_noise(rng, n, 0.04, 0.5, slope=1.0)
    T = ST_TILE_M
    u, v = np.mod(u, T), np.mod(v, T)
    h = T / rows
    r = np.minimum((v / h).astype(np.int64), rows - 1)
    dv = np.minimum(v - r * h, (r + 1) * h - v)
    w = rng.uniform(1.0 - width_jitter, 1.0 + width_jitter, (rows, per_row))
    edges = np.concatenate([np.zeros((rows, 1)), np.cumsum(w, axis=1)], axis=1)
    edges *= T / edges[:, -1:]
    if shift == "half":
        offset = (np.arange(rows) % 2) * 0.5 * T / per_row
    elif shift == "random":
        offset = rng.uniform(0.0, T, rows)
    else:
        offset = np.zeros(rows)
    us = np.mod(u - offset[r], T)
    flat = (edges[:, :-1] + 2 * T * np.arange(rows)[:, None]).ravel()  # rows never interleave
    g = np.searchsorted(flat, us + 2 * T * r, side="right") - 1
    col = np.clip(g - r * per_row, 0, per_row - 1)
    du = np.minimum(us - edges[r, col], edges[r, col + 1] - us)
    a, b = np.maximum(corner_m - du, 0), np.maximum(corner_m - dv, 0)
    dist = np.where((a > 0) & (b > 0), corner_m - np.hypot(a, b), np.minimum(du, dv))
    return (r * per_row + col).astype(np.int64), dist.astype(np.float32)


def cobblestone(rng: np.random.Generator, n: int) -> Surface:
    """Granite setts ~16 x 12.5 cm, hand-laid (irregular joints), domed and polished tops,
    per-stone grey/blue/brown tints, dark sandy joints."""
    px = ST_TILE_M / n
    rows, per_row = 32, 25
    sid, d = bond_layout(rng, n, rows, per_row, width_jitter=0.25, shift="random", warp_m=0.006, corner_m=0.025)
    k = rows * per_row
    joint = 0.006 + 0.004 * rng.random(k)[sid]  # half joint width per stone
    inner = d - joint
    stone = smoothstep(-0.5 * px, 0.5 * px, inner)
    grey = rng.uniform(0.09, 0.24, k)
    tint = rng.normal(0.0, 1.0, (k, 3)) * np.array([0.04, 0.03, 0.04]) + np.array([0.03, 0.01, -0.03])
    col = (grey[:, None] * (1.0 + tint))[sid]
    grain = spectral_noise(rng, n, 1.8 * px, 0.02, slope=0.0)
    col *= (1.0 + 0.18 * grain)[..., None]
    col *= (0.7 + 0.3 * smoothstep(0.0, 0.03, inner))[..., None]  # dirt towards the edges
    sand = srgb(62, 56, 48)[None, None, :] * (1.0 + 0.2 * spectral_noise(rng, n, 2 * px, 0.1, slope=0.5))[..., None]
    mottle = 1.0 + 0.08 * spectral_noise(rng, n, 0.3, ST_TILE_M, slope=1.2)
    albedo = (col * stone[..., None] + sand * (1.0 - stone[..., None])) * mottle[..., None]
    settle = rng.normal(0.0, 0.0015, k)[sid]  # each stone sits a little higher or lower
    dome = 0.010 * smoothstep(0.0, 0.045, inner)
    height = stone * (dome + settle) - 0.004 * (1 - stone)
    rough = stone * (0.82 - 0.28 * smoothstep(0.0, 0.04, inner)) + (1 - stone) * 0.95
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.0)


def pavers(rng: np.random.Generator, n: int) -> Surface:
    """Sidewalk: 20 x 10 cm concrete pavers in running bond, chamfered edges, sand joints,
    per-paver tone, weathering blotches and the odd dark stain."""
    px = ST_TILE_M / n
    rows, per_row = 40, 20
    sid, d = bond_layout(rng, n, rows, per_row, shift="half", corner_m=0.004)
    k = rows * per_row
    inner = d - 0.0015
    paver = smoothstep(-0.5 * px, 0.5 * px, inner)
    tone = rng.normal(1.0, 0.07, k)
    col = srgb(150, 146, 138)[None, None, :] * tone[sid][..., None]
    grain = spectral_noise(rng, n, 1.8 * px, 0.03, slope=0.2)
    weather = spectral_noise(rng, n, 0.1, ST_TILE_M, slope=1.3)
    col *= (1.0 + 0.06 * grain + 0.07 * weather)[..., None]
    col *= (0.8 + 0.2 * smoothstep(0.0, 0.006, inner))[..., None]  # chamfer in shade, dirt
    spots = np.clip(spectral_noise(rng, n, 0.015, 0.08, slope=0.0) - 2.6, 0, 1)  # gum/oil spots
    col *= (1.0 - 0.5 * np.clip(spots * 3, 0, 1))[..., None]
    sand = srgb(92, 86, 76)[None, None, :]
    albedo = col * paver[..., None] + sand * (1.0 - paver[..., None])
    height = paver * 0.004 * smoothstep(0.0, 0.006, inner) - 0.003 * (1 - paver)
    rough = 0.84 + 0.04 * grain - 0.03 * weather + 0.08 * (1 - paver)
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.5)


def _ring_distance(x: np.ndarray, at: float) -> np.ndarray:
    """Distance from x to the nearest ``at + k * ST_TILE_M`` (periodic)."""
    return np.abs(np.mod(x - at + ST_TILE_M / 2, ST_TILE_M) - ST_TILE_M / 2)


def cement(rng: np.random.Generator, n: int) -> Surface:
    """Concrete pavement: lane-wide slabs (longitudinal joints at the lane edges of a 3.5 m
    lane, v = 0.5 +- 0.4375; transverse joints every 2 m at u = 0.25, 0.75), sawn and sealed
    joints, transverse broom texture, per-slab tone, faint oil stains."""
    px = ST_TILE_M / n
    u, v = grid_m(n)
    du = np.minimum(_ring_distance(u, 1.0), _ring_distance(u, 3.0))
    edge = ST_TILE_M / 2 - 1.75
    dv = np.minimum(_ring_distance(v, edge), _ring_distance(v, ST_TILE_M - edge))
    inner = np.minimum(du, dv) - 0.004
    slab = smoothstep(-0.5 * px, 0.5 * px, inner)
    strip = (v < edge) | (v > ST_TILE_M - edge)  # the neighbouring lane's slab
    sid = (np.mod(u - 1.0, ST_TILE_M) >= 2.0).astype(np.int64) + 2 * strip
    tone = rng.normal(1.0, 0.04, 4)[sid]
    broom = spectral_noise(rng, n, 2.5 * px, 0.2, slope=0.3, stretch_u=0.08)  # lines across the road
    sandy = spectral_noise(rng, n, 1.8 * px, 0.02, slope=0.0)
    mottle = spectral_noise(rng, n, 0.2, ST_TILE_M, slope=1.3)
    stain = smoothstep(1.0, 2.5, spectral_noise(rng, n, 0.3, 2.0, slope=1.2))
    grey = tone * (1.0 + 0.05 * mottle + 0.05 * sandy + 0.04 * broom) * (1.0 - 0.12 * stain)
    col = srgb(168, 166, 158)[None, None, :] * grey[..., None]
    col *= (0.85 + 0.15 * smoothstep(0.0, 0.01, inner))[..., None]  # chipped, dirty joint edges
    seal = srgb(40, 39, 38)[None, None, :]
    albedo = col * slab[..., None] + seal * (1.0 - slab[..., None])
    height = -0.006 * (1 - slab)  # broom grooves are sub-texel: diffuse and roughness carry them
    rough = 0.86 + 0.03 * sandy - 0.06 * stain + 0.06 * (1 - slab)
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=2.0)
