"""Asphalt family: new, worn (with tire-polished wheel paths), patch, worn defect floor, pothole
interior (dry and wet) and crack.

Why one body recipe: every asphalt is binder + sand + aggregate; ageing is a change of
parameters (binder oxidises grey and wears off the stone tops, fines ravel out leaving pits,
tires polish the wheel paths), so one parametrised function gives a consistent family. Reference
albedos: fresh asphalt ~0.04-0.05, aged 0.10-0.18 (pavement albedo surveys).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._noise import smoothstep, spectral_noise, stamp_stones
from ._surface import Surface, grid_m, rgb, srgb
from .catalog import ST_TILE_M

WHEEL_OFFSET_M = 0.8  # wheel centres: lane centre (v = 0.5) +- this, a car's half track
WHEEL_BAND_M = 0.5  # full width of a polished wheel path


@dataclass
class _Body:
    binder: np.ndarray  # linear RGB of the binder/sand matrix
    mottle: float = 0.08  # relative low-frequency (0.2-4 m) tone variation
    fine: float = 0.10  # relative texel-scale sand speckle
    stones_per_m2: float = 2500.0
    stone_r: tuple[float, float] = (0.002, 0.006)
    stone_tone: tuple[float, float] = (0.9, 1.5)  # stone albedo relative to the binder
    light_frac: float = 0.04  # share of light (exposed, uncoated) stones
    light_albedo: tuple[float, float] = (0.12, 0.25)
    stone_height_m: float = 0.0015
    pits_per_m2: float = 0.0  # ravelling: lost stones leave dark pits
    pit_r: tuple[float, float] = (0.003, 0.008)
    rim_shade: float = 0.2  # stones darker towards their rims (dirt, shadow): reads as relief


def _body(rng: np.random.Generator, n: int, p: _Body):
    """Albedo (n, n, 3) and height (n, n) of an asphalt surface, plus the stone coverage."""
    px = ST_TILE_M / n
    mottle = spectral_noise(rng, n, 0.15, ST_TILE_M, slope=1.3)
    fine = spectral_noise(rng, n, 1.8 * px, 0.03, slope=0.2)
    macro = spectral_noise(rng, n, 0.012, 0.1, slope=0.5)  # texture depth below the stones
    area = ST_TILE_M ** 2
    count = int(p.stones_per_m2 * area)
    light = rng.random(count) < p.light_frac
    tone = rng.uniform(*p.stone_tone, count)
    grey = np.where(light, rng.uniform(*p.light_albedo, count), tone * float(p.binder.mean()))
    tint = rng.normal(0.0, 0.05, count)  # warm/cool stone tints
    values = grey[:, None] * (1.0 + tint[:, None] * np.array([1.0, 0.2, -1.0]))
    cover, dome, stone_rgb = stamp_stones(rng, n, count, *p.stone_r, values=values)
    albedo = p.binder[None, None, :] * (1.0 + p.fine * fine)[..., None]
    stone_rgb = stone_rgb * (1.0 - p.rim_shade * (1.0 - dome))[..., None]
    albedo = albedo * (1.0 - cover[..., None]) + stone_rgb * cover[..., None]
    albedo *= (1.0 + p.mottle * mottle)[..., None]
    height = p.stone_height_m * (cover * dome + 0.25 * macro)
    if p.pits_per_m2 > 0:
        k = int(p.pits_per_m2 * area)
        pit, pdome, _ = stamp_stones(rng, n, k, *p.pit_r, aspect=1.4)
        albedo *= (1.0 - 0.5 * pit)[..., None]
        height -= 0.004 * pit * (0.3 + pdome)
    return albedo.astype(np.float32), height.astype(np.float32), cover


def wheel_paths(v_m: np.ndarray) -> np.ndarray:
    """1 inside the two tire-polished wheel paths, 0 between them (a function of v only)."""
    centre = ST_TILE_M / 2  # v = 0.5: the lane centreline
    d = np.minimum(np.abs(v_m - (centre - WHEEL_OFFSET_M)), np.abs(v_m - (centre + WHEEL_OFFSET_M)))
    half = WHEEL_BAND_M / 2
    return 1.0 - smoothstep(half - 0.1, half + 0.1, d)


def asphalt(rng: np.random.Generator, n: int) -> Surface:
    """New dense asphalt: near-black binder, fine coated aggregate, a few light stones."""
    albedo, height, cover = _body(rng, n, _Body(binder=srgb(52, 52, 54), mottle=0.06, fine=0.20,
                                                  stones_per_m2=4000, stone_tone=(0.7, 2.0), light_frac=0.04,
                                                  light_albedo=(0.07, 0.15)))
    rough = 0.86 + 0.06 * spectral_noise(rng, n, 0.05, 1.0) - 0.05 * cover
    return Surface(albedo, np.clip(rough, 0, 1), height, normal_strength=2.0)


def asphalt_worn(rng: np.random.Generator, n: int) -> Surface:
    """Aged asphalt: oxidised grey binder, exposed and ravelled aggregate, polished wheel paths
    (smoother, lighter, less rough) at +-``WHEEL_OFFSET_M`` from the lane centre, an oil-stained
    strip between them."""
    albedo, height, cover = _body(rng, n, _Body(binder=srgb(96, 95, 93), mottle=0.10, fine=0.11,
                                                  stones_per_m2=3000, stone_tone=(1.1, 1.9), light_frac=0.12,
                                                  light_albedo=(0.16, 0.30), pits_per_m2=150))
    _, v = grid_m(n)
    band = wheel_paths(v)
    albedo *= (1.0 + 0.10 * band)[..., None]
    # Oil drips between the wheel paths: soft blotches smeared along travel.
    centre = 1.0 - smoothstep(0.15, 0.5, np.abs(v - ST_TILE_M / 2))
    blotch = smoothstep(-0.5, 1.5, spectral_noise(rng, n, 0.1, 2.0, slope=1.2, stretch_u=3.0))
    albedo *= (1.0 - 0.22 * centre * blotch)[..., None]
    height = height * (1.0 - 0.5 * band) - 0.002 * band  # polished flat, slightly rutted
    rough = 0.88 - 0.30 * band + 0.05 * spectral_noise(rng, n, 0.05, 1.0) - 0.05 * cover
    return Surface(albedo, np.clip(rough, 0, 1), height, normal_strength=2.0)


def patch(rng: np.random.Generator, n: int) -> Surface:
    """A recent repair: darker, binder-rich and more uniform than the road around it."""
    albedo, height, cover = _body(rng, n, _Body(binder=srgb(46, 46, 48), mottle=0.025, fine=0.10,
                                                  stone_tone=(0.9, 1.4), light_frac=0.01,
                                                  light_albedo=(0.05, 0.09)))
    rough = 0.72 + 0.03 * spectral_noise(rng, n, 0.05, 1.0)
    return Surface(albedo, np.clip(rough, 0, 1), height, normal_strength=1.6)


def worn(rng: np.random.Generator, n: int) -> Surface:
    """Rut/depression floor: worn asphalt polished all over (tires run in it)."""
    albedo, height, cover = _body(rng, n, _Body(binder=srgb(100, 99, 96), mottle=0.10, fine=0.10,
                                                  stones_per_m2=3000, stone_tone=(1.1, 1.8), light_frac=0.12,
                                                  light_albedo=(0.16, 0.30), pits_per_m2=150))
    rough = 0.62 + 0.06 * spectral_noise(rng, n, 0.05, 1.0)
    return Surface(albedo, np.clip(rough, 0, 1), 0.6 * height, normal_strength=2.0)


def pothole_pair(rng: np.random.Generator, n: int) -> tuple[Surface, Surface]:
    """Pothole interior, dry and wet (same geometry): base course of coarse 1-3 cm aggregate in
    dust. Wet: darker (water fills the pores) and glossy, with puddles in the low spots."""
    albedo, height, cover = _body(rng, n, _Body(binder=srgb(62, 58, 52), mottle=0.15, fine=0.18,
                                                  stones_per_m2=3000, stone_r=(0.004, 0.016), stone_tone=(0.6, 2.2),
                                                  light_frac=0.06, light_albedo=(0.10, 0.18), stone_height_m=0.008,
                                                  rim_shade=0.55))
    dust = np.clip(spectral_noise(rng, n, 0.05, 1.0, slope=1.0), -2, 2)
    albedo *= (1.0 + 0.10 * dust)[..., None]
    height += 0.003 * spectral_noise(rng, n, 0.04, 1.0, slope=1.0)
    rough = 0.94 + 0.03 * spectral_noise(rng, n, 0.02, 0.5)
    dry = Surface(albedo, np.clip(rough, 0, 1), height, normal_strength=1.0)
    low = height < np.quantile(height, 0.35)  # puddles collect in the lowest third
    puddle = smoothstep(0.0, 1.0, (np.quantile(height, 0.35) - height) / 0.002) * low
    wet_albedo = albedo * (0.45 - 0.15 * puddle)[..., None]
    wet_rough = 0.28 - 0.22 * puddle + 0.04 * spectral_noise(rng, n, 0.02, 0.5)
    return dry, Surface(wet_albedo.astype(np.float32), np.clip(wet_rough, 0.02, 1), height, normal_strength=1.0)


def crack(rng: np.random.Generator, n: int) -> Surface:
    """Inside a crack: near-black shadowed gap, a little dust and grit."""
    grit = spectral_noise(rng, n, 1.8 * ST_TILE_M / n, 0.5, slope=0.6)
    albedo = rgb(0.016, 0.015, 0.014)[None, None, :] * (1.0 + 0.25 * grit)[..., None]
    return Surface(albedo.astype(np.float32), 0.95)
