"""Unpaved roadside (verge) surfaces: grass, loose gravel, red lateritic soil.

Why these three: they are what Brazilian highway verges show in survey frames (mixed green and
sun-dried grass in clumps with bare patches, crushed-stone strips, red-brown laterite). A verge
is seen from the lane at 3-15 m, so its maps are stored coarser than the asphalt (~8 mm diffuse
texels) and detail is drawn at the scale that survives that: blade strokes, clumps, stones.
Reference albedos: green grass ~0.15-0.25, dry grass ~0.3, lateritic soil ~0.15-0.25 (red).
"""
from __future__ import annotations

import numpy as np

from ._noise import smoothstep, spectral_noise, stamp_stones
from ._surface import Surface, srgb
from .catalog import ST_TILE_M

LATERITE = srgb(150, 84, 56)  # dry red-brown roadside soil, sRGB picked from survey frames
GREEN_BLADE = srgb(82, 110, 46)
DRY_BLADE = srgb(160, 146, 98)


def _mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per-texel blend of two colours (or colour fields) by ``t`` in [0, 1]."""
    return a * (1.0 - t[..., None]) + b * t[..., None]


def grass(rng: np.random.Generator, n: int) -> Surface:
    """Roadside grass seen from a vehicle: blade strokes (3-6 cm, random directions) over a
    shadowed under-canopy, 10-30 cm clumps, metre-scale patches of sun-dried straw among the
    green, and a few bare soil patches."""
    px = ST_TILE_M / n
    dry = smoothstep(-1.2, 2.0, spectral_noise(rng, n, 0.4, ST_TILE_M, slope=1.6))  # 0 green .. 1 straw
    clump = spectral_noise(rng, n, 0.06, 0.6, slope=0.8)
    bare = smoothstep(1.3, 2.0, spectral_noise(rng, n, 0.12, 1.5, slope=1.2))
    count = int(1800 * ST_TILE_M ** 2)
    jitter = rng.random((count, 2))  # per blade: dryness offset, brightness
    blades, tip, blade_val = stamp_stones(rng, n, count, 0.012, 0.03, aspect=9.0, values=jitter)
    blade_dry = np.clip(dry + 1.2 * (blade_val[..., 0] - 0.5), 0.0, 1.0)
    blade = _mix(GREEN_BLADE[None, None, :], DRY_BLADE[None, None, :], blade_dry)
    blade *= (0.7 + 0.6 * blade_val[..., 1] * (0.75 + 0.25 * tip))[..., None]
    fine = spectral_noise(rng, n, 1.8 * px, 0.03, slope=0.2)
    under = _mix(srgb(34, 42, 22)[None, None, :], srgb(70, 62, 40)[None, None, :], dry)  # lower canopy
    under *= (1.0 + 0.25 * fine)[..., None]
    canopy = np.clip(blades * (0.85 + 0.3 * smoothstep(-1.5, 0.5, clump)), 0.0, 1.0)
    albedo = _mix(under, blade, canopy)
    albedo *= (1.0 + 0.22 * np.clip(clump, -2, 2))[..., None]  # tuft tops lit, gaps in shade
    soil = LATERITE[None, None, :] * 0.85 * (1.0 + 0.15 * fine)[..., None]
    albedo = _mix(albedo, soil, bare * (1.0 - 0.6 * blades))
    height = (0.03 * clump + 0.01 * blades * tip) * (1.0 - bare)
    rough = 0.78 + 0.12 * dry + 0.08 * bare + 0.03 * fine
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=0.6)


def _stone_colours(rng: np.random.Generator, count: int) -> np.ndarray:
    """Crushed-stone tints: mostly grey basalt/granite, some brown and beige, a few laterite."""
    kind = rng.choice(4, count, p=[0.5, 0.27, 0.18, 0.05])
    palette = np.stack([srgb(138, 134, 126), srgb(140, 120, 96), srgb(180, 168, 146), srgb(146, 88, 60)])
    return palette[kind] * rng.uniform(0.6, 1.4, count)[:, None].astype(np.float32)


def gravel(rng: np.random.Generator, n: int) -> Surface:
    """Loose gravel: angular 1-4 cm stones (grey, brown, beige, a few red) resting on smaller
    chippings and brownish dust, each stone shaded towards its rim and casting a dark gap."""
    px = ST_TILE_M / n
    fines = spectral_noise(rng, n, 1.8 * px, 0.05, slope=0.3)
    mottle = spectral_noise(rng, n, 0.2, ST_TILE_M, slope=1.3)
    dust = srgb(96, 88, 76)[None, None, :] * (1.0 + 0.18 * fines)[..., None]  # fines in the stones' shade
    small_n, big_n = int(3500 * ST_TILE_M ** 2), int(1100 * ST_TILE_M ** 2)
    small, s_dome, s_col = stamp_stones(rng, n, small_n, 0.004, 0.009, aspect=1.6,
                                        values=_stone_colours(rng, small_n))
    big, b_dome, b_col = stamp_stones(rng, n, big_n, 0.009, 0.02, aspect=1.8, values=_stone_colours(rng, big_n))
    albedo = _mix(dust, s_col * (0.45 + 0.55 * s_dome)[..., None], small)
    albedo = _mix(albedo * (1.0 - 0.3 * big)[..., None], b_col * (0.4 + 0.6 * b_dome)[..., None], big)
    albedo *= (1.0 + 0.08 * mottle)[..., None]
    height = 0.006 * small * s_dome
    height = np.maximum(height, 0.015 * big * b_dome)
    rough = 0.9 - 0.08 * big * b_dome + 0.03 * fines
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.5)


def soil(rng: np.random.Generator, n: int) -> Surface:
    """Red-brown lateritic soil: crumb and clod micro-relief, a crusted top with hairline cracks,
    paler dry dust and darker compacted/damp patches, scattered dark ironstone pebbles."""
    px = ST_TILE_M / n
    mottle = spectral_noise(rng, n, 0.2, ST_TILE_M, slope=1.3)
    dusty = smoothstep(-1.0, 2.0, spectral_noise(rng, n, 0.3, ST_TILE_M, slope=1.6))
    damp = smoothstep(0.4, 2.2, spectral_noise(rng, n, 0.4, ST_TILE_M, slope=1.6))
    crumb = spectral_noise(rng, n, 1.8 * px, 0.05, slope=0.5)
    clods = spectral_noise(rng, n, 0.02, 0.15, slope=0.8)
    cracks = 1.0 - smoothstep(0.0, 0.08, np.abs(spectral_noise(rng, n, 0.04, 0.4, slope=1.0)))  # ridged zero set
    cracks *= smoothstep(-0.2, 0.8, spectral_noise(rng, n, 0.3, ST_TILE_M, slope=1.0))  # crust only in places
    count = int(90 * ST_TILE_M ** 2)
    tone = rng.uniform(0.25, 0.6, count)
    pebble_rgb = (LATERITE[None, :] * 0.6 * tone[:, None] + srgb(40, 30, 26)[None, :] * (1.0 - tone[:, None]))
    pebbles, p_dome, p_col = stamp_stones(rng, n, count, 0.003, 0.009, aspect=1.4, values=pebble_rgb)
    base = _mix(LATERITE[None, None, :] * np.ones((n, n, 1), np.float32), srgb(168, 112, 80)[None, None, :], dusty)
    base *= (1.0 + 0.10 * mottle + 0.12 * crumb + 0.10 * clods - 0.30 * damp - 0.35 * cracks)[..., None]
    albedo = _mix(base, p_col * (0.6 + 0.4 * p_dome)[..., None], pebbles)
    height = 0.004 * clods + 0.0015 * crumb - 0.003 * cracks + 0.005 * pebbles * p_dome
    rough = 0.93 - 0.10 * damp + 0.03 * crumb - 0.05 * pebbles
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.0)
