"""compose draws defects from a library folder (reconstructed models) mixed with parametric ones."""
from __future__ import annotations

import numpy as np
import pytest
import triangle
from pxr import Usd

from lane_layout import write_lane_layout
from roadtwin_core import DefectModel, RoadtwinError
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.usd import write_defect_asset


def _bowl(name: str, radius: float, depth: float) -> DefectModel:
    """A measured-looking pothole: a bowl with its rim at z = 0 (like a reconstructed asset)."""
    n = 48
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    loop = radius * np.column_stack([np.cos(th), np.sin(th)])
    t = triangle.triangulate({"vertices": loop, "segments": np.column_stack([np.arange(n), (np.arange(n) + 1) % n])},
                             f"pq28a{radius * radius / 60:.8f}Y")
    v = t["vertices"]
    z = -depth * np.clip(1 - (np.hypot(*v.T) / radius) ** 2, 0, 1)
    return DefectModel(name, "pothole", np.column_stack([v, z]), t["triangles"], np.arange(n), source="stereo:01.png")


@pytest.fixture
def layout(tmp_path):
    path = write_lane_layout(tmp_path / "road.usda", 12, 2, "crack")
    return path


def test_library_models_are_placed_with_their_source(layout, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    depth = {}
    for k, (r, d) in enumerate([(0.3, 0.05), (0.45, 0.08)]):
        model = _bowl(f"scan{k}", r, d)
        depth[f"lib_scan{k}"] = model.depth_m  # the mesh's deepest vertex (assets store float32)
        write_defect_asset(model, lib / f"scan{k}.usda")
    out = tmp_path / "out"
    compose(layout, out, library_dir=lib, preview=False, executor="serial")
    stage = Usd.Stage.Open(str(out / "town.usda"))
    defects = [p for p in stage.GetPrimAtPath("/Town/Defects").GetChildren()]
    models = [p.GetAttribute("roadtwin:defect:model").Get() for p in defects]
    assert len(defects) == 12
    assert any(m.startswith("lib_scan") for m in models) and any(m.startswith("crack") for m in models)
    for p, m in zip(defects, models):
        if m.startswith("lib_scan"):
            scale = p.GetAttribute("roadtwin:defect:scale").Get()[2]
            assert p.GetAttribute("roadtwin:defect:depthM").Get() == pytest.approx(depth[m] * scale, rel=1e-6)
    assert (out / "library" / "lib_scan1.usda").exists()


def test_missing_library_folder_is_an_error(layout, tmp_path):
    with pytest.raises(RoadtwinError, match="defect library folder not found"):
        compose(layout, tmp_path / "out", library_dir=tmp_path / "nope", preview=False)
    assert not (tmp_path / "out").exists()


def test_a_usdc_asset_in_the_library_folder_is_used(layout, tmp_path):
    """One rule for which files are assets: a binary .usdc interface file, which ``library add``
    accepts, is drawn from by compose too (it once globbed only *.usda)."""
    lib = tmp_path / "lib"
    lib.mkdir()
    write_defect_asset(_bowl("crate", 0.4, 0.06), lib / "crate.usdc")
    assert (lib / "crate.geom.usda").exists()
    assert Usd.Stage.Open(str(lib / "crate.usdc")).GetRootLayer().GetFileFormat().formatId == "usdc"
    out = tmp_path / "out"
    compose(layout, out, library_dir=lib, preview=False, executor="serial")
    stage = Usd.Stage.Open(str(out / "town.usda"))
    models = [p.GetAttribute("roadtwin:defect:model").Get() for p in stage.GetPrimAtPath("/Town/Defects").GetChildren()]
    assert "lib_crate" in models
    assert (out / "library" / "lib_crate.usda").exists()


def test_an_empty_library_folder_names_the_asset_files_it_looks_for(layout, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "notes.txt").write_text("not an asset")
    with pytest.raises(RoadtwinError, match=r"no defect assets \(\*\.usda, \*\.usd, \*\.usdc\)"):
        compose(layout, tmp_path / "out", library_dir=lib, preview=False, executor="serial")
