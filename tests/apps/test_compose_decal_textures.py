"""A textured library model's decal material in a composed town points at the town's own copy of
the library asset's textures (``library/textures``): each texture is stored once, and the town
still resolves, validates and renders after it is moved to another folder."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import triangle
from pxr import Sdf, Usd, UsdShade, UsdUtils

from lane_layout import write_lane_layout
from roadtwin_core import DefectLook, DefectModel
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.render.scene import build_render_mesh
from roadtwin_core.usd import load_town, validate_stage, write_defect_asset

COLOURS = {"scan0": (40, 90, 200), "scan1": (210, 60, 30)}   # sRGB, one flat diffuse per model


def _textured_bowl(name: str, radius: float, folder) -> DefectModel:
    """A pothole bowl whose look is a flat-coloured 16x16 diffuse, a roughness and a normal map."""
    n = 32
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    loop = radius * np.column_stack([np.cos(th), np.sin(th)])
    t = triangle.triangulate({"vertices": loop, "segments": np.column_stack([np.arange(n), (np.arange(n) + 1) % n])}, "pq28")
    v = t["vertices"]
    z = -0.05 * np.clip(1 - (np.hypot(*v.T) / radius) ** 2, 0, 1)
    r, g, b = COLOURS[name]
    files = {"diffuse": np.dstack([np.full((16, 16), c, np.uint8) for c in (b, g, r, 255)]),
             "roughness": np.full((16, 16), 150 + 40 * int(name[-1]), np.uint8),
             "normal": np.dstack([np.full((16, 16), c, np.uint8) for c in (255, 120 + 16 * int(name[-1]), 128)])}
    textures = {}
    for role, image in files.items():
        textures[role] = str(folder / f"src_{name}_{role}.png")
        cv2.imwrite(textures[role], image)
    st_from_local = ((0.5 / radius, 0.0, 0.5), (0.0, 0.5 / radius, 0.5))   # the footprint's box -> [0, 1]^2
    return DefectModel(name, "pothole", np.column_stack([v, z]), t["triangles"], np.arange(n), source="photo:test.jpg",
                       look=DefectLook(textures, st_from_local))


@pytest.fixture(scope="module")
def town(tmp_path_factory):
    """(composed town folder, source texture bytes by (model, role)); the library folder is gone."""
    tmp = tmp_path_factory.mktemp("decals")
    lib, sources = tmp / "lib", tmp / "sources"
    lib.mkdir()
    sources.mkdir()
    reference = {}
    for name, radius in (("scan0", 0.3), ("scan1", 0.45)):
        model = _textured_bowl(name, radius, sources)
        write_defect_asset(model, lib / f"{name}.usda")
        reference.update({(f"lib_{name}", role): open(path, "rb").read() for role, path in model.look.textures.items()})
    layout = write_lane_layout(tmp / "road.usda", 12, 2)
    out = compose(layout, tmp / "town", library_dir=lib, preview=False, executor="serial", props="none").outdir
    shutil.rmtree(lib)
    shutil.rmtree(sources)
    return out, reference


def _decal_files(town_usda) -> dict[tuple[str, str], str]:
    """(model, role) -> resolved path of every decal material's texture inputs."""
    stage = Usd.Stage.Open(str(town_usda))
    out = {}
    for mat in stage.GetPrimAtPath("/Town/Looks").GetChildren():
        if not mat.GetName().startswith("decal_"):
            continue
        for role, shader in (("diffuse", "Diffuse"), ("roughness", "Roughness"), ("normal", "Normal")):
            asset = UsdShade.Shader(mat.GetChild(shader)).GetInput("file").Get()
            out[(mat.GetName().removeprefix("decal_"), role)] = asset.resolvedPath
    return out


def test_each_texture_is_stored_once_in_the_library_copy(town):
    out, reference = town
    files = _decal_files(out / "town.usda")
    assert {m for m, _ in files} == {"lib_scan0", "lib_scan1"}     # both models placed, both decals
    digests = [hashlib.sha256(p.read_bytes()).hexdigest() for p in out.rglob("*.png")]
    for key, path in files.items():
        assert path and (out / "library" / "textures").resolve() in Path(path).resolve().parents
        assert open(path, "rb").read() == reference[key]
        assert digests.count(hashlib.sha256(reference[key]).hexdigest()) == 1   # once in the whole town
    assert not list((out / "textures").glob("decal_*"))
    _, _, unresolved = UsdUtils.ComputeAllDependencies(str(out / "town.usda"))
    assert unresolved == []


def test_a_moved_town_resolves_validates_and_renders_its_decals(town, tmp_path):
    out, reference = town
    moved = tmp_path / "elsewhere" / "deeper" / "town"
    shutil.copytree(out, moved)
    looks = Sdf.Layer.FindOrOpen(str(moved / "layers" / "looks.usda"))
    for (model, role), path in _decal_files(moved / "town.usda").items():
        assert Path(path).resolve().parent == (moved / "library" / "textures").resolve()
        assert open(path, "rb").read() == reference[(model, role)]
        assert Sdf.ComputeAssetPathRelativeToLayer(looks, f"../library/textures/{model}_{role}.png") == path
    assert not [f for f in validate_stage(moved / "town.usda") if f.severity == "Error"]
    mesh = build_render_mesh(load_town(moved / "town.usda", looks=True))
    for model, (r, g, b) in (("lib_scan0", COLOURS["scan0"]), ("lib_scan1", COLOURS["scan1"])):
        mat = next(m for m in mesh.materials if m.name.endswith(f"decal_{model}"))
        expected = np.where((c := np.array([r, g, b]) / 255) <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        np.testing.assert_allclose(mat.diffuse.reshape(-1, 3).mean(axis=0), expected, atol=2e-3)
