"""Look-alike finishes: what lies on a road without being a defect (oil, tar, rubber, water,
dust, worn and ground-off paint).

Why built on the worn asphalt: each of these is a film or a stain *on* the lane's asphalt, so
the aggregate stays visible through it; the lane's own body (``_asphalt.asphalt_worn``'s
recipe) is darkened, glossed or tinted rather than replaced, and a detector cannot tell them
apart by a foreign texture. Tar is the exception: a filled crack or a bled joint is binder on
top, near-black and glossy with a little sand broadcast on it.
"""
from __future__ import annotations

import numpy as np

from ._asphalt import _Body, _body
from ._finishes import _paint
from ._noise import smoothstep, spectral_noise, stamp_stones
from ._surface import Surface, srgb
from .catalog import ST_TILE_M


def _lane(rng: np.random.Generator, n: int):
    """The driving lane's aged asphalt body (the same recipe as ``asphalt_worn``, no wheel paths)."""
    return _body(rng, n, _Body(binder=srgb(96, 95, 93), mottle=0.10, fine=0.11, stones_per_m2=3000,
                               stone_tone=(1.1, 1.9), light_frac=0.12, light_albedo=(0.16, 0.30), pits_per_m2=150))


def oil_stain(rng: np.random.Generator, n: int) -> Surface:
    """Soaked-in engine oil: 35-65 % of the asphalt's albedo in blotches, slightly glossy."""
    albedo, height, cover = _lane(rng, n)
    soak = smoothstep(-1.5, 1.5, spectral_noise(rng, n, 0.04, 1.0, slope=1.3))
    albedo *= (0.35 + 0.30 * (1 - soak))[..., None] * srgb(120, 118, 122)[None, None, :] / srgb(120, 120, 120)
    rough = 0.55 + 0.15 * (1 - soak) - 0.05 * cover
    return Surface(albedo, np.clip(rough, 0, 1), 0.7 * height, normal_strength=1.5)


def tar(rng: np.random.Generator, n: int) -> Surface:
    """Crack sealant / bled tar: near-black glossy binder with broadcast sand, a few stone tops
    showing, dust in the low spots."""
    px = ST_TILE_M / n
    fine = spectral_noise(rng, n, 1.8 * px, 0.02, slope=0.2)
    mottle = spectral_noise(rng, n, 0.05, 1.0, slope=1.2)
    sand, dome, _ = stamp_stones(rng, n, int(600 * ST_TILE_M ** 2), 0.0015, 0.003)
    albedo = srgb(22, 22, 24)[None, None, :] * (1.0 + 0.10 * fine + 0.15 * mottle)[..., None]
    albedo = albedo * (1 - 0.6 * sand[..., None]) + 0.6 * sand[..., None] * srgb(90, 86, 80)[None, None, :]
    height = 0.0004 * sand * dome + 0.0002 * mottle
    rough = 0.30 + 0.25 * sand + 0.05 * mottle
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.0)


def tyre_mark(rng: np.random.Generator, n: int) -> Surface:
    """Rubber laid on the asphalt by a skid: 40-60 % darker, streaky, polished."""
    albedo, height, cover = _lane(rng, n)
    streak = spectral_noise(rng, n, 0.01, 0.5, slope=0.8)   # isotropic: st is world-planar, marks run any way
    dark = np.clip(0.50 + 0.10 * streak, 0.3, 0.7)
    albedo *= dark[..., None]
    rough = 0.62 + 0.06 * streak - 0.05 * cover
    return Surface(albedo, np.clip(rough, 0, 1), 0.5 * height, normal_strength=1.5)


def wet_patch(rng: np.random.Generator, n: int) -> Surface:
    """Damp asphalt: pores full of water, ~55-75 % of the dry albedo, glossy where it is wettest."""
    albedo, height, cover = _lane(rng, n)
    wet = smoothstep(-1.0, 1.5, spectral_noise(rng, n, 0.08, 2.0, slope=1.4))
    albedo *= (0.75 - 0.20 * wet)[..., None]
    rough = 0.55 - 0.35 * wet
    return Surface(albedo, np.clip(rough, 0.05, 1), height, normal_strength=2.0)


def puddle(rng: np.random.Generator, n: int) -> Surface:
    """Standing water: the asphalt seen darkened under a mirror-smooth surface (flat normal
    but for faint ripples), a little silt."""
    albedo, _, _ = _lane(rng, n)
    silt = smoothstep(0.5, 2.0, spectral_noise(rng, n, 0.05, 1.0, slope=1.2))
    albedo = albedo * 0.45
    albedo = albedo * (1 - 0.3 * silt[..., None]) + 0.3 * silt[..., None] * srgb(92, 78, 62)[None, None, :]
    ripple = 0.00005 * spectral_noise(rng, n, 0.02, 0.3, slope=1.0)
    rough = 0.04 + 0.05 * silt
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), ripple.astype(np.float32), normal_strength=1.0)


def debris(rng: np.random.Generator, n: int) -> Surface:
    """Loose material on the lane: red soil dust, gravel (1-4 cm), straw and bits of litter."""
    albedo, height, cover = _lane(rng, n)
    dust = 0.2 + 0.5 * smoothstep(-1.0, 2.0, spectral_noise(rng, n, 0.05, 1.0, slope=1.4))
    albedo = albedo * (1 - dust[..., None]) + dust[..., None] * srgb(140, 106, 84)[None, None, :]
    k = int(120 * ST_TILE_M ** 2)
    col = srgb(150, 136, 118)[None, :] * rng.uniform(0.4, 1.4, k)[:, None]
    peb, pdome, pcol = stamp_stones(rng, n, k, 0.005, 0.02, aspect=1.8, values=col)
    albedo = albedo * (1 - peb[..., None]) + (pcol * (0.5 + 0.5 * pdome)[..., None]) * peb[..., None]
    k = int(25 * ST_TILE_M ** 2)        # litter and straw: pale, sometimes coloured strokes
    col = np.where(rng.random(k)[:, None] < 0.7, srgb(180, 160, 110)[None, :],
                   rng.uniform(0.1, 0.8, (k, 3)).astype(np.float32))
    lit, _, lcol = stamp_stones(rng, n, k, 0.01, 0.05, aspect=6.0, values=col)
    albedo = albedo * (1 - 0.9 * lit[..., None]) + 0.9 * lit[..., None] * lcol
    height = height + 0.01 * peb * pdome
    rough = 0.9 - 0.05 * cover
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), height.astype(np.float32), normal_strength=1.5)


def paint_worn(rng: np.random.Generator, n: int) -> Surface:
    """Paint worn through to the asphalt: 40-70 % of the coat gone in blotches."""
    s = _paint(rng, n, srgb(225, 225, 218))
    albedo_lane, _, _ = _lane(rng, n)
    gone = smoothstep(-0.6, 0.6, spectral_noise(rng, n, 0.01, 0.4, slope=0.9) + rng.uniform(-0.3, 0.3))
    albedo = s.albedo * (1 - gone[..., None]) + albedo_lane * gone[..., None]
    rough = np.asarray(s.roughness) * (1 - gone) + 0.85 * gone
    return Surface(albedo.astype(np.float32), np.clip(rough, 0, 1), s.height, normal_strength=1.5)


def paint_ghost(rng: np.random.Generator, n: int) -> Surface:
    """Where paint was ground or burnt off: the asphalt paler (abraded binder, paint residue in
    the pores), smoother, with faint residue specks."""
    albedo, height, cover = _lane(rng, n)
    residue = smoothstep(0.8, 2.0, spectral_noise(rng, n, 0.004, 0.05, slope=0.5))
    albedo = albedo * 1.18 + 0.05 * residue[..., None]
    rough = 0.7 - 0.1 * residue - 0.05 * cover
    return Surface(np.clip(albedo, 0, 1).astype(np.float32), np.clip(rough, 0, 1), 0.5 * height, normal_strength=1.5)
