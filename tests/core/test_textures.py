"""Procedural textures (roadtwin_core.looks): determinism, completeness, seamless tiling, budget,
and the appearance facts a renderer relies on.

References are independent of the generators: pixel statistics of the written PNGs decoded with
Pillow, the sRGB transfer curve, the st convention of the catalog (wheel paths at v = 0.5 +- 0.2).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from roadtwin_core import RoadtwinError
from roadtwin_core.looks import (DEFECT_FINISHES, KIND_MATERIAL, MARKING_MATERIAL, OPTIONAL_MATERIALS,
                                 ROAD_MATERIAL_VARIANTS, ST_TILE_M, VERGE_MATERIAL_VARIANTS, all_materials,
                                 write_textures)


@pytest.fixture(scope="module")
def textures(tmp_path_factory):
    """The default set, written once: (folder, specs, seconds)."""
    folder = tmp_path_factory.mktemp("textures")
    t0 = time.process_time()
    specs = write_textures(folder, seed=0)
    return folder, specs, time.process_time() - t0


def load(folder: Path, name: str | None) -> np.ndarray:
    return np.asarray(Image.open(folder / name))


def linear(srgb8: np.ndarray) -> np.ndarray:
    x = srgb8.astype(np.float64) / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def luminance(folder: Path, name: str) -> float:
    rgb = linear(load(folder, name)[..., :3])
    return float((rgb @ np.array([0.2126, 0.7152, 0.0722])).mean())


def rows_at_v(height: int, v_lo: float, v_hi: float) -> np.ndarray:
    """Image rows whose texel centre has st v in [v_lo, v_hi] (row 0 is the top, v = 1)."""
    v = 1.0 - (np.arange(height) + 0.5) / height
    return np.nonzero((v >= v_lo) & (v <= v_hi))[0]


def seam_excess(img: np.ndarray, axis: int) -> float:
    """How far the wrap-around neighbour difference (last vs first column, or row) lies above the
    differences between interior neighbours, in standard deviations of the latter."""
    x = img.astype(np.float64)
    x = x[..., None] if x.ndim == 2 else x
    if axis == 0:
        x = x.transpose(1, 0, 2)
    interior = np.abs(np.diff(x, axis=1)).mean(axis=(0, 2))  # one value per neighbouring column pair
    seam = np.abs(x[:, -1] - x[:, 0]).mean()
    return float((seam - interior.mean()) / max(interior.std(), 1e-9))


def all_files(spec) -> list[str]:
    return [f for f in (spec.diffuse, spec.roughness, spec.normal) if f]


# ---- completeness and determinism ------------------------------------------------------------

def test_every_catalog_material_has_a_spec_with_existing_files(textures):
    folder, specs, _ = textures
    used = {*KIND_MATERIAL.values(), *ROAD_MATERIAL_VARIANTS.values(), *VERGE_MATERIAL_VARIANTS.values(),
            *DEFECT_FINISHES, *MARKING_MATERIAL.values(), *OPTIONAL_MATERIALS, "asphalt", "worn"}
    assert used <= set(all_materials()) <= set(specs)
    for name, spec in specs.items():
        assert spec.name == name
        assert (folder / spec.diffuse).is_file() and Image.open(folder / spec.diffuse).mode == "RGB"
        if spec.roughness:
            assert Image.open(folder / spec.roughness).mode == "L"
        else:
            assert 0.0 <= spec.roughness_value <= 1.0
        if spec.normal:
            assert Image.open(folder / spec.normal).mode == "RGB"
        for f in all_files(spec):
            assert (folder / f).is_file()
    assert specs["pothole_wet"].normal == specs["pothole"].normal  # same geometry, other finish


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    specs = write_textures(a, seed=3, size=128)
    write_textures(b, seed=3, size=128)
    write_textures(c, seed=4, size=128)
    files = sorted(p.name for p in a.iterdir())
    assert files == sorted(p.name for p in b.iterdir()) and len(files) >= 2 * len(specs)
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert (a / "asphalt_diffuse.png").read_bytes() != (c / "asphalt_diffuse.png").read_bytes()


@pytest.mark.parametrize("size", [32, 100.0, True, 1026, 10 ** 5])
def test_bad_size_names_the_parameter(tmp_path, size):
    with pytest.raises(RoadtwinError, match="size"):
        write_textures(tmp_path, size=size)


def test_default_set_fits_the_budget(textures):
    folder, specs, cpu_s = textures
    total = sum(p.stat().st_size for p in folder.iterdir())
    assert total <= 15_000_000
    assert cpu_s < 12.0  # ~3 s CPU on a 2-core dev box; a loose bound against regressions
    assert Image.open(folder / specs["asphalt_worn"].diffuse).size == (1024, 1024)  # ~4 mm texels on 4 m


# ---- tiling ----------------------------------------------------------------------------------

def test_seam_statistic_catches_a_texture_that_does_not_tile(textures):
    folder, specs, _ = textures
    for name in ("asphalt", "asphalt_worn", "pothole", "grass", "gravel"):
        img = load(folder, specs[name].diffuse)
        k = img.shape[0] // 7
        cut = img[:-k, :-k]  # a window of a periodic texture is not periodic
        assert max(seam_excess(cut, 0), seam_excess(cut, 1)) > 4.0, name


def test_every_texture_tiles_seamlessly(textures):
    folder, specs, _ = textures
    for spec in specs.values():
        for f in all_files(spec):
            img = load(folder, f)
            for axis in (0, 1):
                assert seam_excess(img, axis) < 4.0, (f, axis)


# ---- appearance facts ------------------------------------------------------------------------

def test_wheel_paths_of_worn_asphalt_are_smoother_along_the_whole_tile(textures):
    folder, specs, _ = textures
    rough = load(folder, specs["asphalt_worn"].roughness).astype(np.float64) / 255.0
    h = rough.shape[0]
    off = 0.8 / ST_TILE_M  # wheel centres +- 0.8 m from the lane centre (v = 0.5)
    half = 0.15 / ST_TILE_M  # well inside a 0.5 m band
    band = np.concatenate([rows_at_v(h, 0.5 - off - half, 0.5 - off + half),
                           rows_at_v(h, 0.5 + off - half, 0.5 + off + half)])
    between = rows_at_v(h, 0.5 - 0.3 / ST_TILE_M, 0.5 + 0.3 / ST_TILE_M)
    outside = np.concatenate([rows_at_v(h, 0.0, 0.5 - off - 0.45 / ST_TILE_M),
                              rows_at_v(h, 0.5 + off + 0.45 / ST_TILE_M, 1.0)])
    assert rough[band].mean() < rough[between].mean() - 0.15
    assert rough[band].mean() < rough[outside].mean() - 0.15
    # Bands vary across v only: every 0.5 m along u shows the same contrast.
    for chunk in np.array_split(np.arange(rough.shape[1]), 8):
        assert rough[np.ix_(band, chunk)].mean() < rough[np.ix_(between, chunk)].mean() - 0.1
    # New asphalt has no wheel paths.
    new = load(folder, specs["asphalt"].roughness).astype(np.float64) / 255.0
    assert abs(new[band].mean() - new[between].mean()) < 0.03


def test_normal_maps_are_unit_tangent_space_vectors(textures):
    folder, specs, _ = textures
    names = {spec.normal for spec in specs.values() if spec.normal}
    assert len(names) >= 8
    for f in names:
        n = load(folder, f).astype(np.float64) / 255.0 * 2.0 - 1.0
        length = np.linalg.norm(n, axis=-1)
        assert np.abs(length - 1.0).max() < np.sqrt(3) / 255 + 1e-3, f  # 8-bit rounding only
        assert (n[..., 2] > 0.3).all(), f  # out of the surface
        assert abs(n[..., 0].mean()) < 0.02 and abs(n[..., 1].mean()) < 0.02, f  # a periodic surface has no net tilt


def test_relative_brightness_and_gloss(textures):
    folder, specs, _ = textures
    lum = {name: luminance(folder, s.diffuse) for name, s in specs.items()}
    asphalts = ("asphalt", "asphalt_worn", "patch", "worn", "pothole")
    for a in asphalts:
        assert lum["paint_white"] > 3 * lum[a] and lum["paint_yellow"] > 2 * lum[a]
        assert lum["crack"] < 0.6 * lum[a]
    assert 0.03 <= lum["asphalt"] <= 0.08 and 0.08 <= lum["asphalt_worn"] <= 0.2  # pavement albedo surveys
    # The patch is darker and more uniform than the worn road it repairs.
    assert lum["patch"] < 0.7 * lum["asphalt_worn"]
    patch_img = linear(load(folder, specs["patch"].diffuse)).mean(axis=-1)
    worn_img = linear(load(folder, specs["asphalt_worn"].diffuse)).mean(axis=-1)
    assert patch_img.std() / patch_img.mean() < worn_img.std() / worn_img.mean()
    # Wet pothole: darker and glossier than the dry one.
    rough = {n: load(folder, specs[n].roughness).mean() / 255.0 for n in ("pothole", "pothole_wet")}
    assert lum["pothole_wet"] < 0.7 * lum["pothole"] and rough["pothole_wet"] < rough["pothole"] - 0.4
    assert specs["cast_iron"].metallic > 0


def test_verge_materials_read_as_grass_gravel_and_red_soil(textures):
    """Hue facts a randomised verge must keep: grass greener than gravel, lateritic soil redder than
    both, gravel near-neutral; all of them natural-ground albedos (linear, 0.04-0.4)."""
    folder, specs, _ = textures

    def mean_rgb(name: str) -> np.ndarray:
        return linear(load(folder, specs[name].diffuse)[..., :3]).reshape(-1, 3).mean(axis=0)

    rgb = {name: mean_rgb(name) for name in ("grass", "gravel", "soil")}
    g_minus_r = {name: c[1] - c[0] for name, c in rgb.items()}
    assert g_minus_r["grass"] > g_minus_r["gravel"] + 0.01
    assert g_minus_r["soil"] < g_minus_r["gravel"] - 0.05 and g_minus_r["soil"] < g_minus_r["grass"] - 0.05
    assert rgb["soil"][0] > 1.8 * rgb["soil"][1]  # laterite: red clearly above green
    assert abs(g_minus_r["gravel"]) < 0.25 * rgb["gravel"].mean()  # grey-brown, not green, not red
    for name, c in rgb.items():
        assert 0.04 <= float(c @ np.array([0.2126, 0.7152, 0.0722])) <= 0.4, name
    # Every variant a verge may take is a written material.
    assert set(VERGE_MATERIAL_VARIANTS.values()) <= set(specs)
