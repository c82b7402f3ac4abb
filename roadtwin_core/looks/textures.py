"""Seeded procedural textures for every built-in material, written as PNG.

Why per-map resolutions: a 4 m tile needs ~4 mm texels for asphalt aggregate to read at
camera distance, but roughness varies slowly and normals carry little above 8 mm, so those are
stored at 1/2-1/4 of the diffuse size (block means of the same field: still seamless). That
keeps the default set (``size`` 1024) to ~14.7 MB of PNG and ~2 s of CPU (verge and shoulder
maps, seen from further away, at 1/2 and 1/4 of it: ~2.8 MB, ~0.6 s; the look-alikes' small
features at 1/4-1/8: ~1 MB). Images are in the usual order
(row 0 = top = v 1, as UsdUVTexture reads st (0, 0) at the bottom-left); normal maps are
tangent space (x along u, y along v, z out) encoded as (n + 1) / 2 in 0..255; roughness is
linear; diffuse is sRGB.
"""
from __future__ import annotations

import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np
import PIL
from PIL import Image

from ..errors import RoadtwinError
from . import _asphalt, _finishes, _lookalikes, _masonry, _roadside
from ._noise import block_mean, linear_to_srgb8, normal_map, unit_to_u8
from ._surface import Surface
from .catalog import MaterialSpec

DEFAULT_SIZE = 1024
PNG_COMPRESS_LEVEL = 1  # fixed: same bytes for the same seed


def _one(fn: Callable) -> Callable:
    return lambda rng, n: {fn.__name__: fn(rng, n)}


def _pothole(rng: np.random.Generator, n: int) -> dict[str, Surface]:
    dry, wet = _asphalt.pothole_pair(rng, n)
    return {"pothole": dry, "pothole_wet": wet}


# group -> (generator, diffuse / normal / roughness size as a fraction of ``size``, docs).
# A generator may return several materials (pothole and its wet variant share one geometry
# and one normal map).
_GROUPS: dict[str, tuple[Callable, tuple[float, float, float], str]] = {
    "asphalt": (_one(_asphalt.asphalt), (1, 0.5, 0.25), "new dense asphalt"),
    "asphalt_worn": (_one(_asphalt.asphalt_worn), (1, 0.5, 0.25), "aged asphalt, tire-polished wheel paths"),
    "shoulder": (_one(_asphalt.shoulder), (0.5, 0.25, 0.25), "paved shoulder: coarse, weathered, dust and debris"),
    "grass": (_one(_roadside.grass), (0.5, 0.25, 0.25), "roadside grass: green and dry clumps, bare patches"),
    "gravel": (_one(_roadside.gravel), (0.5, 0.25, 0.25), "loose gravel on a verge"),
    "soil": (_one(_roadside.soil), (0.5, 0.25, 0.25), "red-brown lateritic soil"),
    "patch": (_one(_asphalt.patch), (0.5, 0.5, 0.25), "fresh asphalt repair"),
    "worn": (_one(_asphalt.worn), (0.5, 0.5, 0.25), "polished worn asphalt (ruts, depressions)"),
    "pothole": (_pothole, (0.5, 0.5, 0.25), "pothole interior: coarse exposed aggregate (dry / wet)"),
    "crack": (_one(_asphalt.crack), (0.25, 0.25, 0.25), "inside a crack: near-black"),
    "cobblestone": (_one(_masonry.cobblestone), (0.5, 0.5, 0.25), "granite setts"),
    "pavers": (_one(_masonry.pavers), (0.5, 0.5, 0.25), "sidewalk concrete pavers"),
    "cement": (_one(_masonry.cement), (0.5, 0.5, 0.25), "concrete slabs with joints"),
    "paint_white": (_one(_finishes.paint_white), (0.5, 0.25, 0.25), "white road paint, slightly worn"),
    "paint_yellow": (_one(_finishes.paint_yellow), (0.5, 0.25, 0.25), "yellow road paint, slightly worn"),
    "cast_iron": (_one(_finishes.cast_iron), (0.5, 0.5, 0.25), "manhole cover: cast iron, diamond studs, rust"),
    # look-alikes (plugins/roadtwin_lookalikes): small features seen from 5-25 m (a survey pixel
    # there is 1-4 cm): diffuse at 1/4 size (16 mm texels at the default 1024), normal and
    # roughness at 1/8; all eight add ~1 MB
    "oil_stain": (_one(_lookalikes.oil_stain), (0.25, 0.125, 0.125), "look-alike: oil soaked into worn asphalt"),
    "tar": (_one(_lookalikes.tar), (0.25, 0.125, 0.125), "look-alike: crack sealant / bled tar, glossy black"),
    "tyre_mark": (_one(_lookalikes.tyre_mark), (0.25, 0.125, 0.125), "look-alike: rubber skid mark"),
    "wet_patch": (_one(_lookalikes.wet_patch), (0.25, 0.125, 0.125), "look-alike: damp asphalt, glossy"),
    "puddle": (_one(_lookalikes.puddle), (0.25, 0.125, 0.125), "look-alike: standing water, mirror-smooth"),
    "debris": (_one(_lookalikes.debris), (0.25, 0.125, 0.125), "look-alike: soil, gravel and litter on the lane"),
    "paint_worn": (_one(_lookalikes.paint_worn), (0.25, 0.125, 0.125), "look-alike: paint worn through"),
    "paint_ghost": (_one(_lookalikes.paint_ghost), (0.25, 0.125, 0.125), "look-alike: ground-off paint"),
}
# Materials that reuse another's normal map (same geometry, different finish).
_SHARED_NORMAL = {"pothole_wet": "pothole"}


def write_textures(folder: str | Path, seed: int = 0, size: int = DEFAULT_SIZE) -> dict[str, MaterialSpec]:
    """Write every built-in material's textures into ``folder``; return the specs by name.

    ``size``: texels per tile of the most detailed maps (asphalt diffuse); other maps are
    1/2 or 1/4 of it. The same ``seed`` and ``size`` give the same PNG bytes.
    """
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or not 64 <= size <= 8192 or size % 4:
        raise RoadtwinError(f"looks: parameter size must be a multiple of 4 in 64..8192, got {size!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    specs: dict[str, MaterialSpec] = {}
    # PNG encoding (GIL released) runs on one background thread while the next group is
    # generated: each file's bytes depend on its own image only, so the order does not matter
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = []

        def save(path: Path, img: np.ndarray) -> None:
            pending.append(pool.submit(_save, path, img))

        for group, (generate, fractions, doc) in _GROUPS.items():
            sizes = [max(16, int(size * f)) for f in fractions]
            rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(group.encode())])
            n = max(sizes)
            for name, surface in generate(rng, n).items():
                specs[name] = _write_material(folder, name, surface, n, sizes, doc, save)
        for job in pending:
            job.result()                                       # re-raise an encoding error here
    return specs


def _write_material(folder: Path, name: str, s: Surface, n: int, sizes: list[int], doc: str,
                    save: Callable = None) -> MaterialSpec:
    save = save or _save
    diffuse_n, normal_n, rough_n = sizes
    diffuse = f"{name}_diffuse.png"
    save(folder / diffuse, linear_to_srgb8(block_mean(s.albedo, n // diffuse_n)))
    roughness, value = None, 0.8
    if isinstance(s.roughness, np.ndarray):
        roughness = f"{name}_roughness.png"
        save(folder / roughness, unit_to_u8(block_mean(s.roughness, n // rough_n)))
    else:
        value = float(s.roughness)
    normal = None
    if name in _SHARED_NORMAL:
        normal = f"{_SHARED_NORMAL[name]}_normal.png"
    elif s.height is not None:
        normal = f"{name}_normal.png"
        nrm = normal_map(block_mean(s.height, n // normal_n), s.normal_strength)
        save(folder / normal, unit_to_u8((nrm + 1.0) / 2.0))
    return MaterialSpec(name=name, diffuse=diffuse, roughness=roughness, roughness_value=value, normal=normal,
                        metallic=s.metallic, doc=doc)


def png_encoder() -> str:
    """Which library encodes the PNGs here (part of the cache key: the bytes depend on it):
    OpenCV when installed (an optional dependency), else Pillow."""
    try:
        import cv2
    except ImportError:
        return f"pillow {PIL.__version__}"
    return f"opencv {cv2.__version__}"


def _save(path: Path, img: np.ndarray) -> None:
    """PNG at zlib level 1. Through OpenCV's libpng with one fixed row filter (none) where
    OpenCV is installed. Why: Pillow's encoder tries all five filters on every row (adaptive),
    which took ~1.2 s of the set's ~3 s; on these noise textures no filter also compresses
    best (13.7 vs 14.4 MB for the default set). Same library, same bytes."""
    a = np.ascontiguousarray(np.flipud(img))
    try:
        import cv2
    except ImportError:
        Image.fromarray(a).save(path, format="PNG", compress_level=PNG_COMPRESS_LEVEL, optimize=False)
        return
    if a.ndim == 3:
        a = np.ascontiguousarray(a[..., ::-1])                 # OpenCV writes BGR
    ok, buf = cv2.imencode(".png", a, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESS_LEVEL,
                                       cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE])
    if not ok:
        raise RoadtwinError(f"looks: could not encode {path.name} as PNG")
    path.write_bytes(buf.tobytes())
