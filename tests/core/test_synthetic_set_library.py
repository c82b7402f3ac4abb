"""bench/synthetic_set.py's scene library: each scene links every N-th photo asset, and
``--photo-types`` keeps only the named defect types (the isolation runs of issue 22: photo
potholes with parametric cracks, and the reverse), read from each asset's own type attribute."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from bench_script import load_bench_script



def _synthetic_set():
    return load_bench_script("synthetic_set")


def _library(folder: Path, kinds: dict[str, str]) -> Path:
    from roadtwin_core import DefectModel
    from roadtwin_core.usd import write_defect_asset

    verts = np.array([[0, 0, 0], [0.4, 0, 0], [0.4, 0.3, 0], [0, 0.3, 0], [0.2, 0.15, -0.04]], float)
    faces = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    for name, kind in kinds.items():
        # the file name says nothing of the type: the filter must read the asset
        write_defect_asset(DefectModel(name, kind, verts, faces, np.array([0, 1, 2, 3])), folder / f"{name}.usda")
    return folder


def test_photo_types_keep_only_the_named_types_and_every_nth_of_them(tmp_path):
    ss = _synthetic_set()
    lib = _library(tmp_path / "lib", {"a": "pothole", "b": "crack", "c": "pothole", "d": "crack", "e": "pothole"})
    linked = lambda d: sorted(p.name for p in d.glob("*.usda") if not p.name.endswith(".geom.usda"))  # noqa: E731
    assert linked(ss.scene_library(lib, tmp_path / "all", 1, 0)) == ["a.usda", "b.usda", "c.usda", "d.usda", "e.usda"]
    assert linked(ss.scene_library(lib, tmp_path / "pot", 1, 0, ["pothole"])) == ["a.usda", "c.usda", "e.usda"]
    # every 2nd pothole, offset by the scene index
    assert linked(ss.scene_library(lib, tmp_path / "pot1", 2, 1, ["pothole"])) == ["c.usda"]
    assert linked(ss.scene_library(lib, tmp_path / "crk", 2, 0, ["crack"])) == ["b.usda"]
    # each linked asset brings its payload file
    assert (tmp_path / "pot" / "a.geom.usda").exists() and not (tmp_path / "pot" / "b.geom.usda").exists()
    # a type the library lacks: no library at all (compose then runs without --library)
    assert ss.scene_library(lib, tmp_path / "none", 1, 0, ["patch"]) is None and not (tmp_path / "none").exists()


def test_weighted_layout_sets_the_models_per_type_compose_reads(tmp_path):
    """--models-per-type: the copied layout's rules hold it, read back by the layout reader compose uses."""
    from roadtwin_core.usd.layout_io import read_layout

    ss = _synthetic_set()
    repo = Path(__file__).resolve().parents[2]
    out = ss.weighted_layout(repo / "stages/highway.usda", tmp_path / "layout.usda", True, {"pothole": 12.0}, 16)
    rules = read_layout(out).rules
    assert rules.models_per_type == 16 and rules.type_weights["pothole"] == 12.0
    assert rules.type_weights["oil_stain"] == ss.LOOKALIKE_WEIGHTS["oil_stain"]
    assert read_layout(repo / "stages/highway.usda").rules.models_per_type == 6    # the source is untouched


def test_label_range_renders_with_a_class_map_copy_that_holds_it(tmp_path):
    """--label-range crack=8.5,pothole=15: the class map the renders read leaves farther defects
    unlabelled; without it the built-in map (no range) is used as it is."""
    from argparse import Namespace

    from roadtwin_core.render.classmap import load_class_map

    ss = _synthetic_set()
    assert ss.class_map(Namespace(no_camera=False, label_range=None), tmp_path) == "builtin:road_defects_br"
    path = ss.class_map(Namespace(no_camera=False, label_range="crack=8.5,pothole=15"), tmp_path)
    cmap = load_class_map(path)
    assert cmap.label_range_m == (("crack", 8.5), ("pothole", 15.0)) and cmap.camera_targets == "road_defects_br"
