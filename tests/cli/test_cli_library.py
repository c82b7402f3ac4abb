"""``roadtwin library list|show|add`` over tiny defect assets made by the defect-types plugin."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import typer
from pxr import Usd
from typer.testing import CliRunner

from roadtwin_core import PluginManager
from roadtwin_core.apps.library import add_asset
from roadtwin_core.cli.library import library_app
from roadtwin_core.usd import read_defect_asset, write_defect_asset

runner = CliRunner()


@pytest.fixture(scope="module")
def models():
    import roadtwin_defects

    pm = PluginManager(load_entry_points=False)
    pm.register(roadtwin_defects, name="defects")
    types = pm.registry("defect_types")
    out = []
    for i, name in enumerate(("pothole", "bump", "crack")):
        t = types[name]
        out.append(t.generate(dataclasses.replace(t.Params()), np.random.default_rng(i), f"{name}_t{i}"))
    return out


@pytest.fixture
def lib(tmp_path, models) -> Path:
    folder = tmp_path / "lib"
    folder.mkdir()
    for m in models[:2]:
        write_defect_asset(m, folder / f"{m.name}.usda")
    (folder / "notes.usda").write_text('#usda 1.0\n(\n    defaultPrim = "X"\n)\ndef Xform "X" {}\n')
    return folder


def invoke(*args: str, env: dict | None = None):
    app = typer.Typer()
    app.add_typer(library_app, name="library")
    return runner.invoke(app, ["library", *args], env=env or {"COLUMNS": "200"})


def test_list(lib, models):
    res = invoke("list", "-l", str(lib))
    assert res.exit_code == 0, res.output
    for m in models[:2]:
        assert m.name in res.output and m.defect_type in res.output
        assert f"{m.area_m2:.4g}" in res.output and f"{m.volume_m3:.4g}" in res.output
    assert "notes.usda: not a defect asset" in res.output  # named (stderr), not a crash
    assert "geom" not in res.output.split("skipped")[0]


def test_list_env_and_missing(lib, tmp_path):
    res = invoke("list", env={"ROADTWIN_LIBRARY": str(lib), "COLUMNS": "200"})
    assert res.exit_code == 0 and "pothole_t0" in res.output
    res = invoke("list", "-l", str(tmp_path / "nope"))
    assert res.exit_code == 2 and "no such library folder" in res.output


def test_show(lib, models):
    m = models[0]
    res = invoke("show", m.name, "-l", str(lib))
    assert res.exit_code == 0, res.output
    assert "roadtwin:defect:depthM" in res.output and "road_defect" in res.output
    assert f"{m.depth_m:.6g}" in res.output
    assert str(len(m.vertices)) in res.output and str(len(m.faces)) in res.output
    res = invoke("show", "nothing", "-l", str(lib))
    assert res.exit_code == 2 and "no asset 'nothing'" in res.output


def test_add(lib, tmp_path, models):
    src = tmp_path / "src"
    src.mkdir()
    m = models[2]
    write_defect_asset(m, src / f"{m.name}.usda")
    res = invoke("add", str(src / f"{m.name}.usda"), "-l", str(lib))
    assert res.exit_code == 0, res.output
    assert (lib / f"{m.name}.usda").exists() and (lib / f"{m.name}.geom.usda").exists()
    back = read_defect_asset(lib / f"{m.name}.usda")
    assert np.allclose(back.vertices, m.vertices) and np.array_equal(back.faces, m.faces)
    assert not [p for p in lib.iterdir() if p.name.startswith(".")]  # no temporary files left
    assert m.name in invoke("list", "-l", str(lib)).output
    # same name again: refused without --force, accepted with it
    res = invoke("add", str(src / f"{m.name}.usda"), "-l", str(lib))
    assert res.exit_code == 2 and "already exists" in res.output
    assert invoke("add", str(src / f"{m.name}.usda"), "-l", str(lib), "--force").exit_code == 0


def test_add_rejects_bad_assets(lib, tmp_path, models):
    before = sorted(p.name for p in lib.iterdir())
    # geometry payload missing
    src = tmp_path / "src2"
    src.mkdir()
    m = models[2]
    write_defect_asset(m, src / f"{m.name}.usda")
    (src / f"{m.name}.geom.usda").unlink()
    res = invoke("add", str(src / f"{m.name}.usda"), "-l", str(lib))
    assert res.exit_code == 2 and str(src) in res.output
    # not a defect asset, not USD, no file
    for bad, msg in ((lib / "notes.usda", "not a defect asset"), (tmp_path / "x.usda", "no such file")):
        res = invoke("add", str(bad), "-l", str(tmp_path / "other"))
        assert res.exit_code == 2 and msg in res.output
    junk = tmp_path / "junk.usda"
    junk.write_text("this is not usd")
    res = invoke("add", str(junk), "-l", str(lib))
    assert res.exit_code == 2 and "junk.usda" in res.output and len(res.output.strip().splitlines()) == 1
    assert sorted(p.name for p in lib.iterdir()) == before  # nothing written


def test_add_asset_api(tmp_path, models):
    src = tmp_path / "a"
    src.mkdir()
    write_defect_asset(models[1], src / "b.usda")
    out = add_asset(src / "b.usda", tmp_path / "new_lib")
    assert out == tmp_path / "new_lib" / "b.usda"
    stage = Usd.Stage.Open(str(out))
    assert stage.GetDefaultPrim().GetAttribute("roadtwin:defect:type").Get() == models[1].defect_type


def test_one_rule_for_asset_files(tmp_path, models):
    """A .usdc interface is listed and added like a .usda one; a file list and compose would not
    see (a payload, another suffix) is refused by add."""
    src = tmp_path / "src"
    src.mkdir()
    write_defect_asset(models[0], src / "binary.usdc")
    lib = tmp_path / "lib"
    assert add_asset(src / "binary.usdc", lib) == lib / "binary.usdc"
    res = invoke("list", "-l", str(lib))
    assert res.exit_code == 0 and "binary" in res.output and "skipped" not in res.output
    for name in ("binary.geom.usda",):
        res = invoke("add", str(src / name), "-l", str(tmp_path / "other"))
        assert res.exit_code == 2 and "not a library asset file" in res.output
    (src / "notes.usdz").write_bytes(b"")
    res = invoke("add", str(src / "notes.usdz"), "-l", str(tmp_path / "other"))
    assert res.exit_code == 2 and "not a library asset file" in res.output
    assert not (tmp_path / "other").exists()
