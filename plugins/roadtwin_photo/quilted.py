"""One photo surface quilted from several windows of the same kind of road (core-free: numpy,
OpenCV).

A surface's own window is joined by the clean windows of other frames that look most like it
(nearest in standardised CIELAB lightness, chroma and texture contrast, within
``same_road``): more photographed road to draw blocks from, so fewer blocks come from the same
spot. Every window is back-projected at the tile's texel, brought to the group's coarsest
photo sample (a sharp block beside a soft one would show), cleared of its light ramp and of
the colour that varies over more than ``flatten_m`` (wheel paths, a stain's halo, a darker
lane half: in a tile that repeats every ``ST_TILE_M`` any of them comes back as a band every
4 m, and blocks cut from two of them show as rectangles), and shifted, per channel, to the
surface's own mean colour (each keeps its grain and contrast).
:func:`.quilting.quilt_torus` lays them into one seamless ``ST_TILE_M`` tile.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.ndimage import gaussian_filter

from .photo_io import read_rgb
from .quilting import quilt_torus
from .rectify import OrthoGrid, PhotoRig, rectify
from .road_area import axis_samples_m, uniform_resolution
from .seamless import remove_light_ramp


def same_road(seed, pool: Sequence, exclude: Sequence, count: int, max_distance: float, scale: np.ndarray) -> list:
    """``seed`` and up to ``count - 1`` candidates of ``pool`` (not in ``exclude``) nearest to it
    in standardised features, each at most ``max_distance`` from it; nearest first."""
    taken = {id(c) for c in exclude} | {id(seed)}
    dist = [(float(np.linalg.norm((c.features - seed.features) / scale)), str(c.image), c) for c in pool
            if id(c) not in taken]
    near = sorted((d, name, c) for d, name, c in dist if d <= max_distance)
    return [seed] + [c for _, _, c in near[:max(0, count - 1)]]


def window_grid(c, search: OrthoGrid, window_m: float, overlap: float, texel: float) -> OrthoGrid:
    """The candidate's window with its blend overlap, at ``texel``, from its search square's corner."""
    side = int(round(window_m * (1 + overlap) / texel))
    return OrthoGrid(search.x_max - c.row0 * search.texel, search.y_max - c.col0 * search.texel, texel, side, side)


def source_windows(sources: Sequence, rig: PhotoRig, grids: Sequence[OrthoGrid], uniform: bool,
                   flatten_m: float) -> tuple[list[np.ndarray], float, float]:
    """Each source's window in texture orientation (columns along travel), float, at the group's
    coarsest photo sample (returned: along and across travel, m), light ramp removed, colour
    that varies over more than ``flatten_m`` (a Gaussian's sigma; 0: none) taken out, its mean
    colour the first one's."""
    orthos, along, across = [], [], []
    for c, grid in zip(sources, grids):
        rgb = read_rgb(Path(c.image))
        h, w = rgb.shape[:2]
        a, b = axis_samples_m(rig, grid, w, h)
        orthos.append(rectify(rgb, rig, grid))
        along.append(a)
        across.append(b)
    out = []
    for ortho, grid in zip(orthos, grids):
        if uniform:
            ortho = uniform_resolution(ortho, grid.texel, max(along), max(across))
        window = remove_light_ramp(np.rot90(ortho, -1))
        if flatten_m > 0:
            window = window - gaussian_filter(window, (flatten_m / grid.texel,) * 2 + (0,), mode="reflect")
        out.append(window)
    target = remove_light_ramp(np.rot90(orthos[0], -1)).reshape(-1, orthos[0].shape[-1]).mean(axis=0)
    return [w - w.reshape(-1, w.shape[-1]).mean(axis=0) + target for w in out], max(along), max(across)


def quilted_tile(windows: Sequence[np.ndarray], size: int, block_texels: float,
                 rng: np.random.Generator) -> np.ndarray:
    """(size, size, 3) uint8 sRGB tile that wraps seamlessly, quilted from the source windows."""
    tile = quilt_torus(list(windows), size, block_texels, rng)
    return np.clip(tile + 0.5, 0, 255).astype(np.uint8)
