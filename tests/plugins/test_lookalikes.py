"""Look-alikes (plugins/roadtwin_lookalikes, issue 22 item 4): each composes into a town that
validates, is labelled road in the stage's semantics, renders with its own material, and maps
to the road classes (background / ego lane, never crack or pothole) under builtin:road_defects_br;
same seed, same bytes."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import triangle
from pxr import Usd, UsdSemantics, UsdShade

import roadtwin_cdt
import roadtwin_defects
import roadtwin_lookalikes
import roadtwin_warp_render
from roadtwin_core import ComposeRules, DefectType, FixedDefect, PluginManager, RoadSegment, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.apps.render import RenderOptions, run_render
from roadtwin_core.render.cameras import RIG_PRESETS, look_from
from roadtwin_core.render.classmap import load_class_map
from roadtwin_core.usd import validate_stage, write_layout

LANE_W = 3.5
SPACING = 22.0
TYPES = [cls.name for cls in roadtwin_lookalikes.ALL]
# The finish each look-alike should wear: tar for the bituminous ones, paint for the paint, each
# stain and mark its own (what a survey camera sees; the types name it, core names no type).
FINISH = {"oil_stain": "oil_stain", "tar_stain": "tar", "sealed_crack": "tar", "patch_seam": "tar",
          "tyre_mark": "tyre_mark", "wet_patch": "wet_patch", "puddle": "puddle", "debris": "debris",
          "worn_paint": "paint_worn", "ghost_paint": "paint_ghost"}


def _strip(name, kind, x0, x1, y0, y1, centerline=None) -> RoadSegment:
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "pqa4")
    return RoadSegment(name, kind, t["vertices"], t["triangles"], centerline)


def _layout(pm) -> TownLayout:
    """A straight two-lane road; one look-alike of each type pinned in the right lane every
    ``SPACING`` m (yawed along travel), then a pothole and a crack (the class map's classes)."""
    length = SPACING * (len(TYPES) + 3)
    segs = []
    for i, x in enumerate(np.arange(0.0, length, 20.0)):
        x1 = x + 20.0
        segs += [_strip(f"r{i}", "driving", x, x1, -LANE_W, 0.0, np.array([[x, -LANE_W / 2], [x1, -LANE_W / 2]])),
                 _strip(f"l{i}", "driving", x, x1, 0.0, LANE_W, np.array([[x1, LANE_W / 2], [x, LANE_W / 2]])),
                 _strip(f"sr{i}", "shoulder", x, x1, -LANE_W - 2.0, -LANE_W),
                 _strip(f"sl{i}", "shoulder", x, x1, LANE_W, LANE_W + 2.0)]
    fixed = []
    for k, t in enumerate(TYPES + ["pothole", "crack"]):
        dtype = pm.get("defect_types", t)
        params = dataclasses.asdict(dtype.sample_params(np.random.default_rng([7, k])))
        if t == "tyre_mark":
            params["length_m"] = 4.0                    # the whole mark in one survey view
        fixed.append(FixedDefect(f"F{k:02d}_{t}", t, params, x=SPACING * (k + 1), y=-LANE_W / 2 - 0.3, seed=k))
    rules = ComposeRules(defect_count=0, seed=3, surface="flat", models_per_type=1,
                         type_weights={"pothole": 1.0}, edge_margin_m=0.2)
    lay = TownLayout("Town", segs, rules)
    lay.fixed = fixed
    return lay


@pytest.fixture(scope="module")
def pm():
    m = PluginManager(load_entry_points=False)
    for mod, name in ((roadtwin_cdt, "cdt"), (roadtwin_defects, "defects"), (roadtwin_lookalikes, "lookalikes"),
                      (roadtwin_warp_render, "warp_render")):
        m.register(mod, name=name)
    return m


def _compose(pm, base: Path) -> Path:
    base.mkdir(parents=True, exist_ok=True)
    write_layout(_layout(pm), base / "road.usda")
    return compose(base / "road.usda", base / "town", preview=False, executor="serial", pm=pm).town


@pytest.fixture(scope="module")
def town(pm, tmp_path_factory):
    return _compose(pm, tmp_path_factory.mktemp("lk"))


def test_each_lookalike_is_flush_and_declares_itself(pm):
    for t in TYPES:
        dtype = pm.get("defect_types", t)
        assert isinstance(dtype, DefectType) and dtype.semantic_class == "road_lookalike"
        for k in range(3):
            rng = np.random.default_rng([1, k])
            m = dtype.generate(dtype.sample_params(rng), rng, f"{t}_{k}")
            assert m.defect_type == t and m.area_m2 > 0.005
            assert 0.0 <= m.vertices[:, 2].min() and m.vertices[:, 2].max() <= 0.005, t   # flush or a few mm


@pytest.mark.parametrize("kind, params, area", [
    ("worn_paint", {"length_m": 2.0, "width_m": 0.15}, 2.0 * 0.15),                  # a dash: length x width
    ("patch_seam", {"length_m": 1.5, "width_m": 1.0, "sides": 1, "band_m": 0.05}, 1.5 * 0.05),
    # mitred corners: the outer square gained equals the inner one lost, so centreline x band
    ("patch_seam", {"length_m": 1.5, "width_m": 1.0, "sides": 2, "band_m": 0.05}, (1.5 + 1.0) * 0.05),
    ("patch_seam", {"length_m": 1.5, "width_m": 1.0, "sides": 3, "band_m": 0.05}, (2 * 1.5 + 1.0) * 0.05),
])
def test_footprint_areas_match_closed_forms(pm, kind, params, area):
    dtype = pm.get("defect_types", kind)
    m = dtype.generate(dataclasses.replace(dtype.Params(), **params), np.random.default_rng(0), kind)
    assert m.area_m2 == pytest.approx(area, rel=0.01), kind


def test_smooth_blob_is_its_ellipse():
    """Roughness 0: an ellipse, simplified by at most a quarter of the 5 cm mesh spacing, so it
    loses at most perimeter x 1.25 cm of area (inscribed: never gains)."""
    a, b = 0.5, 0.3
    stain = roadtwin_lookalikes.OilStain()
    m = stain.generate(stain.Params(length_m=2 * a, width_m=2 * b, roughness=0.0), np.random.default_rng(0), "o")
    perimeter = math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b)))       # Ramanujan
    assert math.pi * a * b - perimeter * 0.05 / 4 <= m.area_m2 <= math.pi * a * b


def test_each_lookalike_composes_validates_and_is_labelled_road(town):
    assert not [f for f in validate_stage(town) if f.severity == "Error"]
    stage = Usd.Stage.Open(str(town))
    seen = {}
    for prim in stage.GetPrimAtPath("/Town/Defects").GetChildren():
        t = prim.GetAttribute("roadtwin:defect:type").Get()
        seen[t] = list(UsdSemantics.LabelsAPI(prim, "class").GetLabelsAttr().Get())
        mat = UsdShade.MaterialBindingAPI(prim.GetChildren()[0]).ComputeBoundMaterial()[0]
        assert mat.GetPrim().GetName() == {**FINISH, "pothole": "pothole", "crack": "crack"}[t], t
    for t in TYPES:
        assert seen[t] == ["road", "road_lookalike", t], t
        assert (town.parent / "textures" / f"{FINISH[t]}_diffuse.png").is_file()
    assert seen["pothole"] == ["road_defect", "pothole"]
    # the library assets the town wrote say the same
    lib = Usd.Stage.Open(str(town.parent / "library" / "fixed_F00_oil_stain.usda"), load=Usd.Stage.LoadNone)
    assert list(UsdSemantics.LabelsAPI(lib.GetDefaultPrim(), "class").GetLabelsAttr().Get()) == \
        ["road", "road_lookalike", "oil_stain"]


def _poses(path: Path) -> Path:
    """A survey-rig camera 8 m behind each pinned feature, in its lane, looking along travel."""
    rig = RIG_PRESETS["survey"]
    poses = [{"cam_to_world": look_from((SPACING * (k + 1) - 8.0, -LANE_W / 2, rig.height_m), 0.0,
                                        math.radians(rig.pitch_deg)).tolist()} for k in range(len(TYPES) + 2)]
    path.write_text(json.dumps(poses))
    return path


def _options(tmp_path: Path, **kw) -> RenderOptions:
    return RenderOptions(rig="survey", size="256x160", frames=len(TYPES) + 2, poses=_poses(tmp_path / "poses.json"),
                         formats="mmseg,coco", executor="serial", **kw)


def test_lookalike_pixels_are_road_under_road_defects_br(town, pm, tmp_path):
    out = tmp_path / "r"
    run_render(town, out, _options(tmp_path, classmap="builtin:road_defects_br", randomize=True, seed=2), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    types = {i["id"]: i["type"] for i in meta["instances"]}
    cmap = load_class_map("road_defects_br")
    road = {cmap.classes.index("background"), cmap.classes.index("ego_lane")}
    pixels = dict.fromkeys(TYPES, 0)
    for fr in meta["frames"]:
        labels = cv2.imread(str(out / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
        inst = cv2.imread(str(out / fr["files"]["instance"]), cv2.IMREAD_UNCHANGED)
        for k, t in types.items():
            sel = inst == k
            if t in pixels and sel.any():
                pixels[t] += int(sel.sum())
                assert set(np.unique(labels[sel]).tolist()) <= road, (t, np.unique(labels[sel]))
    assert all(n > 0 for n in pixels.values()), json.dumps(pixels)      # every look-alike is seen
    # the class map's camera targets drove the randomizer: every frame aims its exposure
    assert all("target_luminance" in fr["randomization"]["effects"] for fr in meta["frames"])


def test_lookalikes_render_with_their_own_material(town, pm, tmp_path):
    """Without randomization: inside an oil stain the image is darker than the lane around it,
    a worn paint dash lighter."""
    out = tmp_path / "r"
    run_render(town, out, _options(tmp_path), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    types = {i["id"]: i["type"] for i in meta["instances"]}
    contrast = {}
    for fr in meta["frames"]:
        rgb = cv2.imread(str(out / fr["files"]["rgb"]), cv2.IMREAD_GRAYSCALE).astype(float)
        inst = cv2.imread(str(out / fr["files"]["instance"]), cv2.IMREAD_UNCHANGED)
        for k, t in types.items():
            sel = inst == k
            if sel.sum() < 20:
                continue
            ring = cv2.dilate(sel.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool) & (inst == 0)
            contrast[t] = rgb[sel].mean() / max(rgb[ring].mean(), 1.0)
    assert contrast["oil_stain"] < 0.9 and contrast["tar_stain"] < 0.7, contrast
    assert contrast["worn_paint"] > 1.1, contrast


def test_same_seed_same_bytes(town, pm, tmp_path):
    again = _compose(pm, tmp_path / "again")
    for rel in ("layers/defects.usda", "layers/defects.geom.usdc", "layers/semantics.usda", "layers/looks.usda",
                "layers/roads.geom.usdc", "textures/tar_diffuse.png", "textures/oil_stain_diffuse.png"):
        assert (town.parent / rel).read_bytes() == (again.parent / rel).read_bytes(), rel
