"""One surface's tile: a single window made seamless and repeated k x k, or the windows of one
kind of road quilted into a whole ``ST_TILE_M`` tile, with the maps derived from it and its
record (``materials.json``). Called by :mod:`.surfaces` (which picks the windows, and whose
``PhotoSurfacesParams`` is ``p`` here); core-free: numpy.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .photo_io import license_for, read_rgb
from .quilted import quilted_tile, source_windows, window_grid
from .quilting import block_grid, fitting_block
from .rectify import OrthoGrid, PhotoRig, rectify
from .road_area import axis_samples_m, ground_sample_m, uniform_resolution
from .seamless import (derived_maps, linear_luminance, linear_to_srgb8, make_seamless, period_correlation, seam_ratio,
                       srgb_to_linear)

# metres of road per texture repeat: roadtwin_core.looks.ST_TILE_M (not public to plugins);
# compose --road-textures refuses a materials.json whose st_tile_m differs from it
ST_TILE_M = 4.0


@dataclass
class Surface:
    name: str
    candidate: Any                   # surfaces.Candidate (its own window)
    tile: np.ndarray                 # (N, N, 3) uint8 sRGB, one ST_TILE_M repeat
    roughness: np.ndarray            # (N, N) float 0..1
    normal: np.ndarray               # (N, N, 3) unit vectors
    record: dict


def cut_surface(name: str, c, rig: PhotoRig, views: dict, p, license_text: str) -> Surface:
    """Back-project the candidate's window at the tile's texel, make it seamless, derive maps."""
    n = int(round(p.size / c.repeats))
    m = max(2, int(round(n * p.overlap)))
    texel = ST_TILE_M / (n * c.repeats)
    rgb = read_rgb(c.image)
    h, w = rgb.shape[:2]
    search = views[(w, h)].grid
    x_top, y_left = search.x_max - c.row0 * search.texel, search.y_max - c.col0 * search.texel
    fine = OrthoGrid(x_top, y_left, texel, n + m, n + m)
    along_m, across_m = axis_samples_m(rig, fine, w, h)
    ortho = rectify(rgb, rig, fine)                           # rows forward-up, columns left-to-right
    if p.uniform:
        ortho = uniform_resolution(ortho, texel, along_m, across_m)
    # texture orientation: columns along travel (s), rows from left (top, t = 1) to right
    crop = np.rot90(ortho, -1)
    tile = np.clip(make_seamless(crop, n) + 0.5, 0, 255).astype(np.uint8)
    gsd = _gsd_range(rig, fine, w, h)
    record = {
        "source": f"photo {c.image} (road window {ST_TILE_M / c.repeats:.3f} m, {x_top - (n + m) * texel:.2f}.."
                  f"{x_top:.2f} m ahead); license: {license_text}",
        "frame": str(c.image), "label": str(c.label), "license": license_text,
        "window_m": round(ST_TILE_M / c.repeats, 6), "repeats": c.repeats, "texel_m": texel,
        "overlap_texels": m, "window_road_m": {"x": [round(x_top - (n + m) * texel, 4), round(x_top, 4)],
                                               "y": [round(y_left - (n + m) * texel, 4), round(y_left, 4)]},
        "ground_sample_m": [round(v, 5) for v in gsd], "clean_square_m": round(c.clean_m, 3),
        "shade": round(c.shade, 4), "photo_sample_m": {"along": round(along_m, 5), "across": round(across_m, 5)},
        "uniform_resolution": p.uniform,
        "seam_ratio": seam_ratio(tile), "seam_ratio_unblended": seam_ratio(crop[:n, :n]),
        "lab_mean_lightness": round(float(c.features[0]), 2), "lab_mean_chroma": round(float(c.features[1]), 2),
        "lab_lightness_std": round(float(c.features[2]), 2), "rig": asdict(rig),
        "doc": f"asphalt photographed in {c.image.name} ({license_text.split(' (')[0]}), seamless, repeating every "
               f"{ST_TILE_M / c.repeats:g} m",
    }
    return with_maps(Surface(name, c, tile, None, None, record))


def quilt_surface(name: str, group: list, rig: PhotoRig, views: dict, p,
                  license_override: str | None, rng: np.random.Generator) -> Surface:
    """The first candidate's window and those of its kind of road quilted into one seamless
    ``ST_TILE_M`` tile (:mod:`.quilted`), maps derived from it."""
    seed, texel = group[0], ST_TILE_M / p.size
    search = next(iter(views.values())).grid                  # the search grid is the same for every image size
    _, block = block_grid(p.size, p.patch_m / texel)
    grids = [window_grid(c, search, ST_TILE_M / c.repeats, p.overlap, texel) for c in group]
    keep = [i for i, g in enumerate(grids) if i == 0 or g.rows >= block]   # windows smaller than a block lend none
    group, grids = [group[i] for i in keep], [grids[i] for i in keep]
    windows, along_m, across_m = source_windows(group, rig, grids, p.uniform, p.flatten_m)
    block_texels = fitting_block(p.size, p.patch_m / texel, min(g.rows for g in grids))
    _, block = block_grid(p.size, block_texels)
    tile = quilted_tile(windows, p.size, block_texels, rng)
    n = int(round(ST_TILE_M / seed.repeats / texel))
    licenses = [license_override or license_for(c.image) for c in group]
    sources = [{"frame": str(c.image), "label": str(c.label), "license": lic,
                "window_m": round(ST_TILE_M / c.repeats, 6), **_window_on_road(g)}
               for c, g, lic in zip(group, grids, licenses)]
    record = {
        "source": f"photos {', '.join(str(c.image) for c in group)} (road windows quilted into one {ST_TILE_M:g} m "
                  f"tile); license: {licenses[0]}",
        "frame": str(seed.image), "label": str(seed.label), "license": licenses[0],
        "window_m": round(ST_TILE_M / seed.repeats, 6), "repeats": 1, "texel_m": texel,
        **_window_on_road(grids[0]), "sources": sources,
        "synthesis": {"method": "toroidal image quilting, minimum-error boundary cuts (Efros & Freeman 2001)",
                      "block_texels": block, "patch_m": p.patch_m,
                      "flatten_m": p.flatten_m, "seed": p.seed, "windows": len(windows)},
        "ground_sample_m": [round(v, 5) for v in _gsd_range(rig, grids[0], *_size_of(views, seed))],
        "clean_square_m": round(seed.clean_m, 3), "shade": round(seed.shade, 4),
        "photo_sample_m": {"along": round(along_m, 5), "across": round(across_m, 5)}, "uniform_resolution": p.uniform,
        "seam_ratio": seam_ratio(tile), "seam_ratio_unblended": seam_ratio(windows[0][:n, :n]),
        "window_period_correlation": period_correlation(tile, n),
        "lab_mean_lightness": round(float(seed.features[0]), 2), "lab_mean_chroma": round(float(seed.features[1]), 2),
        "lab_lightness_std": round(float(seed.features[2]), 2), "rig": asdict(rig),
        "doc": f"asphalt photographed in {seed.image.name} and {len(group) - 1} frame(s) like it "
               f"({licenses[0].split(' (')[0]}), quilted into one seamless tile repeating every {ST_TILE_M:g} m",
    }
    return with_maps(Surface(name, seed, tile, None, None, record))


def _window_on_road(g: OrthoGrid) -> dict:
    x0, y0 = g.x_max - g.rows * g.texel, g.y_max - g.cols * g.texel
    return {"window_road_m": {"x": [round(x0, 4), round(g.x_max, 4)], "y": [round(y0, 4), round(g.y_max, 4)]}}


def _size_of(views: dict, c) -> tuple[int, int]:
    """The image size of a candidate's frame (the views are keyed by it)."""
    import cv2

    if len(views) == 1:
        return next(iter(views))
    img = cv2.imread(str(c.image), cv2.IMREAD_UNCHANGED)
    return img.shape[1], img.shape[0]


def with_maps(s: Surface) -> Surface:
    """Roughness and normal derived from the tile (one window, or the quilted ``ST_TILE_M``
    tile), then all three repeated k x k (``record["repeats"]``)."""
    roughness, normal = derived_maps(s.tile, s.record["texel_m"])
    k = s.record["repeats"]
    return Surface(s.name, s.candidate, s.tile, roughness, normal, s.record) if k == 1 else Surface(
        s.name, s.candidate, np.tile(s.tile, (k, k, 1)), np.tile(roughness, (k, k)), np.tile(normal, (k, k, 1)),
        s.record)


def as_albedo(s: Surface, factor: float) -> Surface:
    """A photo holds light x albedo x exposure: scaled in linear light by one factor common to
    all surfaces, the maps derived again from the scaled colour."""
    n = s.tile.shape[0] // s.record["repeats"]
    one = linear_to_srgb8(srgb_to_linear(s.tile[:n, :n]) * factor)
    record = {**s.record, "albedo_scale": round(factor, 6), "mean_linear_luminance": round(linear_luminance(one), 5)}
    return with_maps(Surface(s.name, s.candidate, one, None, None, record))


def _gsd_range(rig: PhotoRig, grid: OrthoGrid, width: int, height: int) -> tuple[float, float]:
    coarse = OrthoGrid(grid.x_max, grid.y_max, grid.texel * grid.rows / 8, 8, 8)
    g = ground_sample_m(rig, coarse, width, height)
    return float(g.min()), float(g.max())

