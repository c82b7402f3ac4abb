"""Hostile input for ``import``, ``render``, ``sweep``, ``plan`` and ``reconstruct`` (#14 item 3).

A corpus is built here from the shipped samples (``tests/data/opendrive``, the stereo pothole
disparity frames, ``default_car.toml``, the class map, ``stages/defect_avoidance.usda`` composed
once) by mutating them: truncation, empty files, wrong types, NaN / inf, out-of-range and huge
values, directories where files are expected, outputs under a regular file (tests run as root on
CI, so chmod would not stop a write), and every path under a folder whose name has a space and
non-ASCII characters. Each case runs through the real entry point (``roadtwin_core.cli.main``,
in-process) and must end in

- exit 0 with its output written, or
- exit 2 with exactly one line on stderr that names the input at fault (file, option),

never a traceback, never "internal error", never a partial or temporary output, never a changed
input (the inputs a case names are hashed before and after). Case ids start with the command
name: ``pytest --collect-only tests/cli/test_hostile_cmds.py`` lists them (the project's addopts
already add -q; a second -q only prints the total).
"""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_run import run_main

REPO = Path(__file__).resolve().parents[2]
XODR = REPO / "tests/data/opendrive/curved_road_default.xodr"
DISP = REPO / "tests/data/stereo_pothole/disp_tg/01.png"
CAR = REPO / "roadtwin_core/vehicle/default_car.toml"
CLASSMAP = REPO / "roadtwin_core/render/classmaps/road_defects_br.toml"
LAYOUT = REPO / "stages/defect_avoidance.usda"


# --------------------------------------------------------------------------- the corpus
def _xodr_variants(text: str) -> dict[str, str]:
    """Mutations of a small OpenDRIVE file (two roads, one straight then arc geometry each)."""
    geo = 'length="20.0">'
    assert geo in text and 'a="3.5"' in text
    return {
        "truncated.xodr": text[: len(text) // 2],
        "empty.xodr": "",
        "not_xml.xodr": "road 1 is 20 m long\n",
        "no_roads.xodr": "<OpenDRIVE><header revMajor='1' revMinor='4'/></OpenDRIVE>",
        "wrong_root.xodr": "<CRG><road/></CRG>",
        "zero_length.xodr": text.replace(geo, 'length="0.0">', 1),
        "negative_length.xodr": text.replace(geo, 'length="-20.0">', 1),
        "nan_length.xodr": text.replace(geo, 'length="nan">', 1),
        "inf_length.xodr": text.replace(geo, 'length="inf">', 1),
        "huge_length.xodr": text.replace(geo, 'length="1e300">', 1),
        "text_length.xodr": text.replace(geo, 'length="twenty">', 1),
        "no_length.xodr": text.replace(geo, ">", 1),
        "nan_x.xodr": text.replace('x="0.0"', 'x="nan"', 1),
        "huge_x.xodr": text.replace('x="0.0"', 'x="1e308"', 1),
        "nan_hdg.xodr": text.replace('hdg="1.5707963267948966"', 'hdg="nan"', 1),
        "nan_width.xodr": text.replace('a="3.5"', 'a="nan"', 1),
        "inf_width.xodr": text.replace('a="3.5"', 'a="inf"', 1),
        "huge_width.xodr": text.replace('a="3.5"', 'a="1e9"', 1),
        "negative_width.xodr": text.replace('a="3.5"', 'a="-3.5"'),
        "no_width_a.xodr": text.replace('a="3.5"', "", 1),
        "text_lane_id.xodr": text.replace('<lane id="1"', '<lane id="one"', 1),
        "no_road_id.xodr": text.replace(' id="1" junction', " junction", 1),
        "huge_curvature.xodr": text.replace('curvature="', 'curvature="1e12" x="', 1),
        "binary.xodr": "\x00\x01\xff" * 50,
    }


def _vehicle_variants(text: str) -> dict[str, str]:
    return {
        "nan_mass.toml": text.replace("sprung_mass_kg = 1300.0", "sprung_mass_kg = nan"),
        "inf_mass.toml": text.replace("sprung_mass_kg = 1300.0", "sprung_mass_kg = inf"),
        "zero_mass.toml": text.replace("sprung_mass_kg = 1300.0", "sprung_mass_kg = 0.0"),
        "negative_spring.toml": text.replace("spring_front_n_per_m = 30000.0", "spring_front_n_per_m = -30000.0"),
        "huge_mass.toml": text.replace("sprung_mass_kg = 1300.0", "sprung_mass_kg = 1e300"),
        "text_mass.toml": text.replace("sprung_mass_kg = 1300.0", 'sprung_mass_kg = "heavy"'),
        "bool_mass.toml": text.replace("sprung_mass_kg = 1300.0", "sprung_mass_kg = true"),
        "list_mass.toml": text.replace("sprung_mass_kg = 1300.0", "sprung_mass_kg = [1300.0]"),
        "huge_radius.toml": text.replace("tire_radius_m = 0.31", "tire_radius_m = 1e9"),
        "zero_wheelbase.toml": text.replace("wheelbase_m = 2.7", "wheelbase_m = 0.0"),
        "cg_outside.toml": text.replace("cg_to_front_axle_m = 1.1", "cg_to_front_axle_m = 9.0"),
        "unknown_key.toml": text + "\nturbo = true\n",
        "unknown_model.toml": text.replace('model = "full"', 'model = "hovercraft"'),
        "truncated.toml": text[: len(text) // 3] + "[body",
        "empty.toml": "",
        "name_table.toml": text.replace('name = "default_car"', "name = 3"),
        "latin1.toml": "name = \"caf\xe9\"\n",
        "vehicle.yaml": "name: car\n",
        "body_string.toml": 'name = "x"\nmodel = "full"\nbody = "heavy"\n',
    }


def _pose_variants() -> dict[str, str]:
    good = {"position": [30.0, -1.75, 1.6], "yaw_deg": 0.0, "pitch_deg": -20.0}
    return {
        "poses_good.json": json.dumps({"poses": [good]}),
        "poses_empty.json": "",
        "poses_truncated.json": json.dumps({"poses": [good]})[:20],
        "poses_none.json": json.dumps({"poses": []}),
        "poses_nan.json": json.dumps({"poses": [{**good, "position": [float("nan"), 0, 1.6]}]}),
        "poses_inf_yaw.json": json.dumps({"poses": [{**good, "yaw_deg": float("inf")}]}),
        "poses_huge.json": json.dumps({"poses": [{**good, "position": [1e300, 0, 1.6]}]}),
        "poses_far.json": json.dumps({"poses": [{**good, "position": [1e6, 1e6, 1.6]}]}),
        "poses_text.json": json.dumps({"poses": [{**good, "position": "here"}]}),
        "poses_short.json": json.dumps({"poses": [{**good, "position": [1.0, 2.0]}]}),
        "poses_number.json": json.dumps(42),
        "poses_items_numbers.json": json.dumps({"poses": [1, 2, 3]}),
        "poses_matrix_3x3.json": json.dumps({"poses": [{"cam_to_world": np.eye(3).tolist()}]}),
        "poses_matrix_singular.json": json.dumps({"poses": [{"cam_to_world": np.zeros((4, 4)).tolist()}]}),
        "poses_text_pitch.json": json.dumps({"poses": [{**good, "pitch_deg": "down"}]}),
    }


def _classmap_variants(text: str) -> dict[str, str]:
    return {
        "cm_empty.toml": "",
        "cm_truncated.toml": text[: len(text) // 2] + "\n[map",
        "cm_no_classes.toml": 'name = "x"\n',
        "cm_classes_number.toml": 'name = "x"\nclasses = 3\n',
        "cm_dilate_nan.toml": text.replace("crack = 1", "crack = nan"),
        "cm_binary.toml": "\x00\xff\xfe",
    }


def _points(n: int = 4000, seed: int = 0) -> np.ndarray:
    """A 2 m x 1 m road patch (2000 points/m2) with a 2 % cross slope and 5 mm noise."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0, -0.5], [2, 0.5], size=(n, 2))
    z = 0.02 * xy[:, 1] + rng.normal(0, 0.005, n)
    return np.column_stack([xy, z])


def _write_pointclouds(d: Path) -> None:
    import open3d as o3d

    pts = _points()
    np.save(d / "cloud.npy", pts)
    np.savez(d / "cloud.npz", points=pts)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    o3d.io.write_point_cloud(str(d / "cloud.ply"), pc, write_ascii=True)
    o3d.io.write_point_cloud(str(d / "cloud.pcd"), pc, write_ascii=True)
    ply = (d / "cloud.ply").read_text()
    (d / "truncated.ply").write_text(ply[: len(ply) // 3])
    (d / "header_only.ply").write_text(ply.split("end_header")[0] + "end_header\n")
    (d / "garbage.ply").write_text("not a point cloud\n")
    (d / "garbage.pcd").write_bytes(b"\x00\x01" * 100)
    bad = pts.copy()
    bad[::2] = np.nan
    np.save(d / "half_nan.npy", bad)
    np.save(d / "all_nan.npy", np.full((100, 3), np.nan))
    np.save(d / "all_inf.npy", np.full((100, 3), np.inf))
    np.save(d / "huge.npy", np.column_stack([pts[:, :2] * 1e12, pts[:, 2]]))
    np.save(d / "flat_2d.npy", pts[:, :2])
    np.save(d / "vector.npy", pts[:, 0])
    np.save(d / "three_points.npy", pts[:3])
    np.save(d / "empty.npy", np.zeros((0, 3)))
    np.save(d / "collinear.npy", np.column_stack([np.linspace(0, 10, 500), np.zeros(500), np.zeros(500)]))
    np.save(d / "strings.npy", np.array([["a", "b", "c"]] * 10))
    np.save(d / "objects.npy", np.array([None, 1, "x"], dtype=object), allow_pickle=True)
    np.savez(d / "no_points.npz", colours=pts)
    np.savez(d / "empty_archive.npz")
    np.savez(d / "labels_mismatch.npz", points=pts, labels=np.full(10, 40))
    np.savez(d / "labels_none_road.npz", points=pts, labels=np.full(len(pts), 7))
    (d / "truncated.npy").write_bytes((d / "cloud.npy").read_bytes()[:200])
    (d / "truncated.npz").write_bytes((d / "cloud.npz").read_bytes()[:300])
    (d / "cloud.las").write_bytes(b"LASF")
    # poses: KITTI (3x4 per line) and TUM (t x y z qx qy qz qw)
    (d / "poses_kitti.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    (d / "poses_tum.txt").write_text("0 0 0 0 0 0 0 1\n")
    (d / "poses_two.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 2)
    (d / "poses_nan.txt").write_text("1 0 0 nan 0 1 0 0 0 0 1 0\n")
    (d / "poses_inf.txt").write_text("0 inf 0 0 0 0 0 1\n")
    (d / "poses_words.txt").write_text("one two three\n")
    (d / "poses_seven.txt").write_text("1 2 3 4 5 6 7\n")
    (d / "poses_zero_quat.txt").write_text("0 0 0 0 0 0 0 0\n")
    (d / "poses_singular.txt").write_text("0 0 0 0 0 0 0 0 0 0 0 0\n")
    (d / "poses_empty.txt").write_text("")
    (d / "extrinsic_nan.txt").write_text("nan " * 16)
    (d / "extrinsic_short.txt").write_text("1 0 0 0\n")


def _write_stereo(d: Path) -> None:
    """Disparity frames: a quarter-size copy of a shipped transformed frame and its mutations."""
    import cv2

    full = cv2.imread(str(DISP), cv2.IMREAD_UNCHANGED)
    small = cv2.resize(full, (full.shape[1] // 4, full.shape[0] // 4), interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(str(d / "disp.png"), small)
    raw = (d / "disp.png").read_bytes()
    (d / "disp_truncated.png").write_bytes(raw[: len(raw) // 2])
    (d / "disp_header.png").write_bytes(raw[:60])
    (d / "disp_text.png").write_text("not an image\n")
    (d / "disp_empty.png").write_bytes(b"")
    cv2.imwrite(str(d / "disp_zero.png"), np.zeros_like(small))
    cv2.imwrite(str(d / "disp_const.png"), np.full_like(small, 1000))
    cv2.imwrite(str(d / "disp_1x1.png"), small[:1, :1])
    cv2.imwrite(str(d / "disp_3x2.png"), small[:2, :3])
    cv2.imwrite(str(d / "disp_row.png"), small[:1])
    cv2.imwrite(str(d / "disp_rgb.png"), cv2.cvtColor((small // 256).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    f = small.astype(np.float32) / 256.0
    np.save(d / "disp.npy", f)
    nan = f.copy()
    nan[::3] = np.nan
    np.save(d / "disp_partnan.npy", nan)
    np.save(d / "disp_allnan.npy", np.full_like(f, np.nan))
    np.save(d / "disp_inf.npy", np.where(f > 0, np.inf, 0).astype(np.float32))
    np.save(d / "disp_huge.npy", f * 1e30)
    np.save(d / "disp_neg.npy", -f)
    np.save(d / "disp_3d.npy", np.stack([f, f, f]))
    np.save(d / "disp_1d.npy", f[0])
    np.save(d / "disp_complex.npy", f.astype(np.complex64))
    np.save(d / "disp_bool.npy", f > 1)
    np.save(d / "disp_strings.npy", np.array([["a"] * 4] * 4))
    (d / "disp.pfm").write_bytes(b"Pf\n4 4\n-1.0\n" + np.ones(16, "<f4").tobytes())
    (d / "disp_truncated.pfm").write_bytes(b"Pf\n400 400\n-1.0\n" + np.ones(16, "<f4").tobytes())
    (d / "disp_badheader.pfm").write_bytes(b"PF\nwide high\n")
    (d / "disp.tiff").write_bytes(b"II*\x00")
    # a rectified pair (SGBM path): a textured image and its 8 px shift
    rng = np.random.default_rng(0)
    tex = cv2.resize(rng.integers(0, 255, (40, 60), dtype=np.uint8), (240, 160), interpolation=cv2.INTER_LINEAR)
    cv2.imwrite(str(d / "left.png"), tex)
    cv2.imwrite(str(d / "right.png"), np.roll(tex, -8, axis=1))
    cv2.imwrite(str(d / "right_small.png"), tex[:80, :120])
    (d / "right_truncated.png").write_bytes((d / "right.png").read_bytes()[:100])


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """The corpus folder (its path has a space and non-ASCII characters) and a composed town."""
    import functools

    import roadtwin_core.apps.compose.run as compose_mod
    from roadtwin_core.looks import write_textures

    base = tmp_path_factory.mktemp("hostile")
    c = base / "corpus ü 道路"
    c.mkdir()
    (c / "a_file").write_text("a regular file, not a folder\n")
    (c / "a folder.xodr").mkdir()
    (c / "a folder.toml").mkdir()
    (c / "a folder.json").mkdir()
    (c / "a folder.png").mkdir()
    (c / "a folder.npy").mkdir()
    (c / "a folder.usda").mkdir()
    (c / "empty.usda").write_text("")
    shutil.copy(XODR, c / "road ü.xodr")
    for name, text in _xodr_variants(XODR.read_text()).items():
        (c / name).write_text(text, encoding="latin-1" if name == "binary.xodr" else "utf-8")
    car = CAR.read_text()
    shutil.copy(CAR, c / "car ü.toml")
    for name, text in _vehicle_variants(car).items():
        (c / name).write_bytes(text.encode("latin-1" if name == "latin1.toml" else "utf-8"))
    (c / "car.json").write_text('{"name": "car", "model": "full", "body": {"sprung_mass_kg": NaN}}')
    (c / "car_list.json").write_text("[1, 2, 3]")
    for name, text in _pose_variants().items():
        (c / name).write_text(text)
    cm = CLASSMAP.read_text()
    shutil.copy(CLASSMAP, c / "classes ü.toml")
    for name, text in _classmap_variants(cm).items():
        (c / name).write_bytes(text.encode("latin-1", "replace") if name == "cm_binary.toml" else text.encode())
    _write_pointclouds(c)
    _write_stereo(c)
    # The town: the planning scenario composed once; 64-texel textures keep it fast (the
    # textures' size is not what these cases test).
    town = compose_mod.compose(LAYOUT, c / "town", preview=False, executor="serial",
                               texture_writer=functools.partial(write_textures, size=64)).town
    (c / "sweep_dir").mkdir()
    (c / "sweep_dir" / "recommendations.json").write_text("{not json")
    (c / "sweep_nan").mkdir()
    (c / "sweep_nan" / "recommendations.json").write_text('[{"defect": "d", "recommended_speed_kmh": NaN}]')
    return {"c": c, "town": town}


# --------------------------------------------------------------------------- the cases
OK, ERR, ANY = "ok", "err", "any"


def case(cid: str, args: list[str], expect: str = ERR, names: str | None = None):
    """``names``: a regex the one error line must match (the input at fault); ``{c}`` = corpus,
    ``{town}`` = the composed town stage, ``{out}`` = this case's (fresh) output path."""
    return pytest.param(args, expect, names, id=cid)


def _imp(name: str, expect: str = ERR, names: str | None = None):
    return case(f"import-{name.rsplit('.', 1)[0]}", ["import", "opendrive", "{c}/" + name, "-o", "{out}.usda"],
                expect, names or re_name(name))


def re_name(name: str) -> str:
    import re

    return re.escape(name)


IMPORT = [
    _imp("road ü.xodr", OK),
    *[_imp(n) for n in ("truncated.xodr", "empty.xodr", "not_xml.xodr", "no_roads.xodr", "wrong_root.xodr",
                        "zero_length.xodr", "negative_length.xodr", "nan_length.xodr", "inf_length.xodr",
                        "huge_length.xodr", "text_length.xodr", "no_length.xodr", "nan_x.xodr", "huge_x.xodr",
                        "nan_hdg.xodr", "nan_width.xodr", "inf_width.xodr", "huge_width.xodr",
                        "negative_width.xodr", "no_width_a.xodr", "text_lane_id.xodr", "no_road_id.xodr",
                        "huge_curvature.xodr", "binary.xodr", "a folder.xodr")],
    case("import-missing-file", ["import", "opendrive", "{c}/nope.xodr", "-o", "{out}.usda"], ERR, "nope"),
    case("import-unknown-importer", ["import", "shapefile", "{c}/road ü.xodr", "-o", "{out}.usda"], ERR, "shapefile"),
    case("import-output-under-a-file", ["import", "opendrive", "{c}/road ü.xodr", "-o", "{c}/a_file/x.usda"],
         ERR, "a_file"),
    case("import-output-is-a-folder", ["import", "opendrive", "{c}/road ü.xodr", "-o", "{c}/a folder.usda"],
         ERR, "a folder"),
    case("import-output-not-usd", ["import", "opendrive", "{c}/road ü.xodr", "-o", "{out}.txt"], ERR, "txt"),
]

# small and fast: 32x24 px, one or two frames, serial executor
R = ["render", "{town}", "-o", "{out}", "--size", "32x24", "--frames", "1", "--executor", "serial"]
RP = [*R, "--poses", "{c}/poses_good.json"]
RENDER = [
    case("render-ok-lanes", R, OK),
    case("render-ok-poses", RP, OK),
    case("render-ok-classmap-file", [*R, "--classmap", "{c}/classes ü.toml"], OK),
    *[case(f"render-{n.split('.')[0]}", [*R, "--poses", "{c}/" + n], ERR, re_name(n))
      for n in ("poses_empty.json", "poses_truncated.json", "poses_none.json", "poses_nan.json", "poses_inf_yaw.json",
                "poses_huge.json", "poses_text.json", "poses_short.json", "poses_number.json",
                "poses_items_numbers.json", "poses_matrix_3x3.json", "poses_matrix_singular.json",
                "poses_text_pitch.json", "a folder.json")],
    case("render-poses_far", [*R, "--poses", "{c}/poses_far.json"], ANY, "poses_far"),
    *[case(f"render-classmap-{n.split('.')[0]}", [*R, "--classmap", "{c}/" + n], ERR, re_name(n))
      for n in ("cm_empty.toml", "cm_truncated.toml", "cm_no_classes.toml", "cm_classes_number.toml",
                "cm_dilate_nan.toml", "cm_binary.toml", "a folder.toml")],
    case("render-classmap-missing", [*R, "--classmap", "{c}/nope.toml"], ERR, "nope"),
    case("render-classmap-unknown-builtin", [*R, "--classmap", "builtin:nope"], ERR, "nope"),
    case("render-stage-missing", ["render", "{c}/nope.usda", "-o", "{out}"], ERR, "nope"),
    case("render-stage-folder", ["render", "{c}/a folder.usda", "-o", "{out}"], ERR, "a folder"),
    case("render-stage-empty", ["render", "{c}/empty.usda", "-o", "{out}"], ERR, "empty"),
    case("render-stage-xodr", ["render", "{c}/road ü.xodr", "-o", "{out}"], ERR, "road ü"),
    case("render-size-zero", [*R, "--size", "0x0"], ERR, "--size"),
    case("render-size-text", [*R, "--size", "big"], ERR, "--size"),
    case("render-size-huge", [*R, "--size", "99999x99999"], ERR, "--size"),
    case("render-size-negative", [*R, "--size", "-32x24"], ERR, "--size"),
    case("render-frames-zero", [*R, "--frames", "0"], ERR, "--frames"),
    case("render-frames-huge", [*R, "--frames", "1000000000"], ERR, "--frames"),
    case("render-frames-text", [*R, "--frames", "many"], ERR, "frames"),
    case("render-hfov-nan", [*R, "--hfov", "nan"], ERR, "--hfov"),
    case("render-hfov-zero", [*R, "--hfov", "0"], ERR, "--hfov"),
    case("render-hfov-180", [*R, "--hfov", "180"], ERR, "--hfov"),
    case("render-hfov-negative", [*R, "--hfov", "-60"], ERR, "--hfov"),
    case("render-height-nan", [*R, "--height", "nan"], ERR, "--height"),
    case("render-height-inf", [*R, "--height", "inf"], ERR, "--height"),
    case("render-height-huge", [*R, "--height", "1e300"], ERR, "--height"),
    case("render-height-negative", [*R, "--height", "-1"], ERR, "--height"),
    case("render-pitch-nan", [*R, "--pitch", "nan"], ERR, "--pitch"),
    case("render-pitch-out-of-range", [*R, "--pitch", "120"], ERR, "--pitch"),
    case("render-baseline-nan", [*R, "--stereo", "--baseline", "nan"], ERR, "--baseline"),
    case("render-baseline-huge", [*R, "--stereo", "--baseline", "1e300"], ERR, "--baseline"),
    case("render-baseline-negative", [*R, "--stereo", "--baseline", "-0.5"], ERR, "--baseline"),
    case("render-seed-negative", [*R, "--seed", "-1"], ERR, "--seed"),
    case("render-seed-huge", [*R, "--seed", "99999999999999999999999"], ERR, "seed"),
    case("render-workers-zero", [*R, "--workers", "0"], ERR, "--workers"),
    case("render-weather", [*R, "--weather", "snowstorm"], ERR, "weather"),
    case("render-rig", [*R, "--rig", "periscope"], ERR, "periscope"),
    case("render-views", [*R, "--views", "defects:nan"], ERR, "--views"),
    case("render-views-share", [*R, "--views", "defects:7"], ERR, "--views"),
    case("render-formats", [*R, "--formats", "jpeg2000"], ERR, "jpeg2000"),
    case("render-formats-empty", [*R, "--formats", ","], ERR, "format"),
    case("render-renderer", [*R, "--renderer", "povray"], ERR, "povray"),
    case("render-backend", [*R, "--backend", "raytracer9000"], ERR, "backend"),
    case("render-device", [*R, "--device", "tpu"], ERR, "device"),
    case("render-executor", [*R, "--executor", "cluster"], ERR, "cluster"),
    case("render-material", [*R, "--material", "chocolate"], ERR, "chocolate"),
    case("render-events-speed-nan", [*R, "--events", "--event-frames", "2", "--speed", "nan"], ERR, "--speed"),
    case("render-events-speed-negative", [*R, "--events", "--event-frames", "2", "--speed", "-5"], ERR, "--speed"),
    case("render-events-rate-zero", [*R, "--events", "--event-frames", "2", "--event-rate", "0"], ERR, "--event-rate"),
    case("render-events-rate-inf", [*R, "--events", "--event-frames", "2", "--event-rate", "inf"], ERR,
         "--event-rate"),
    case("render-events-frames-huge", [*R, "--events", "--event-frames", "1000000000"], ERR, "--event-frames"),
    case("render-events-threshold-nan", [*R, "--events", "--event-frames", "2", "--event-threshold", "nan"], ERR,
         "--event-threshold"),
    case("render-event-size", [*R, "--events", "--event-frames", "2", "--event-size", "0x0"], ERR, "--event-size"),
    case("render-output-under-a-file", [*R[:2], "-o", "{c}/a_file/out", *R[4:]], ERR, "a_file"),
    case("render-output-is-a-file", [*R[:2], "-o", "{c}/a_file", *R[4:]], ERR, "a_file"),
]

def opt(base: list[str], name: str, value: str) -> list[str]:
    """``base`` with option ``name`` set to ``value`` (as ``--name=value``: negatives are values)."""
    i = base.index(name)
    return [*base[:i], f"{name}={value}", *base[i + 2:]]


S = ["sweep", "--surface", "flat", "--length", "20", "--speeds", "30", "--defects", "small_shallow", "--no-plots",
     "-o", "{out}"]
SWEEP = [
    case("sweep-ok-flat", S, OK),
    case("sweep-ok-vehicle-file", [*S, "--vehicle", "{c}/car ü.toml"], OK),
    *[case(f"sweep-vehicle-{n.split('.')[0]}", [*S, "--vehicle", "{c}/" + n], ERR, re_name(n))
      for n in ("nan_mass.toml", "inf_mass.toml", "zero_mass.toml", "negative_spring.toml", "huge_mass.toml",
                "text_mass.toml", "bool_mass.toml", "list_mass.toml", "huge_radius.toml", "zero_wheelbase.toml",
                "cg_outside.toml", "unknown_key.toml", "unknown_model.toml", "truncated.toml", "empty.toml",
                "name_table.toml", "latin1.toml", "vehicle.yaml", "body_string.toml", "car.json", "car_list.json",
                "a folder.toml")],
    case("sweep-vehicle-missing", [*S, "--vehicle", "{c}/nope.toml"], ERR, "nope"),
    case("sweep-speeds-nan", opt(S, "--speeds", "nan"), ERR, "speed"),
    case("sweep-speeds-inf", opt(S, "--speeds", "inf"), ERR, "speed"),
    case("sweep-speeds-zero-step", opt(S, "--speeds", "5:60:0"), ERR, "speed"),
    case("sweep-speeds-huge-count", opt(S, "--speeds", "0:1e9:0.001"), ERR, "speed"),
    case("sweep-speeds-negative", opt(S, "--speeds", "-30"), ERR, "speed"),
    case("sweep-speeds-huge", opt(S, "--speeds", "1e12"), ERR, "speed"),
    case("sweep-speeds-text", opt(S, "--speeds", "fast"), ERR, "speed"),
    case("sweep-length-nan", opt(S, "--length", "nan"), ERR, "length"),
    case("sweep-length-negative", opt(S, "--length", "-20"), ERR, "length"),
    case("sweep-length-huge", opt(S, "--length", "1e12"), ERR, "length"),
    case("sweep-surface-bad", opt(S, "--surface", "iso8608:Z"), ERR, "surface"),
    case("sweep-dt-nan", [*S, "--dt", "nan"], ERR, "dt"),
    case("sweep-dt-zero", [*S, "--dt", "0"], ERR, "dt"),
    case("sweep-imu-rate-zero", [*S, "--imu-rate", "0"], ERR, "imu"),
    case("sweep-imu-rate-nan", [*S, "--imu-rate", "nan"], ERR, "imu"),
    case("sweep-tire-zero", [*S, "--tire", "0x0"], ERR, "tire"),
    case("sweep-tire-huge", [*S, "--tire", "100000x100000"], ERR, "tire"),
    case("sweep-offsets-nan", [*S, "--offsets", "nan"], ERR, "offset"),
    case("sweep-offsets-huge", [*S, "--offsets", "1e9"], ANY, "offset"),
    case("sweep-offsets-text", [*S, "--offsets", "left"], ERR, "offset"),
    case("sweep-seed-negative", [*S, "--seed", "-3"], ERR, "seed"),
    case("sweep-defects-unknown", opt(S, "--defects", "nope"), ERR, "nope"),
    case("sweep-defects-empty", opt(S, "--defects", ","), ERR, "defects"),
    case("sweep-backend", [*S, "--backend", "havok"], ERR, "havok"),
    case("sweep-device", [*S, "--device", "abacus"], ERR, "abacus"),
    case("sweep-stage-and-surface", ["sweep", "{town}", *S[1:]], ERR, "surface"),
    case("sweep-stage-missing", ["sweep", "{c}/nope.usda", "-o", "{out}"], ERR, "nope"),
    case("sweep-stage-folder", ["sweep", "{c}/a folder.usda", "-o", "{out}"], ERR, "a folder"),
    case("sweep-stage-empty", ["sweep", "{c}/empty.usda", "-o", "{out}"], ERR, "empty"),
    case("sweep-output-under-a-file", [*S[:-1], "{c}/a_file/out"], ERR, "a_file"),
    case("sweep-output-is-a-file", [*S[:-1], "{c}/a_file"], ERR, "a_file"),
]

P = ["plan", "{town}", "--planner", "astar", "-o", "{out}"]
PLAN = [
    case("plan-ok", P, OK),
    case("plan-start-nan", [*P, "--start", "nan,0,0"], ERR, "start"),
    case("plan-start-inf", [*P, "--start", "inf,0,0"], ERR, "start"),
    case("plan-start-text", [*P, "--start", "here"], ERR, "start"),
    case("plan-start-two", [*P, "--start", "1,2"], ANY, "start"),
    case("plan-start-off-map", [*P, "--start", "1e9,1e9,0"], ERR, "start"),
    case("plan-goal-huge", [*P, "--goal", "1e300,0,0"], ERR, "goal"),
    case("plan-goal-yaw-nan", [*P, "--goal", "100,-1.75,nan"], ERR, "goal"),
    case("plan-resolution-zero", [*P, "--resolution", "0"], ERR, "resolution"),
    case("plan-resolution-nan", [*P, "--resolution", "nan"], ERR, "resolution"),
    case("plan-resolution-tiny", [*P, "--resolution", "1e-6"], ERR, "resolution"),
    case("plan-resolution-huge", [*P, "--resolution", "1e9"], ERR, "resolution"),
    case("plan-collision", [*P, "--collision", "hull"], ERR, "collision"),
    case("plan-planner", [*P[:2], "--planner", "teleport", *P[4:]], ERR, "teleport"),
    case("plan-seed-negative", [*P, "--seed", "-1"], ERR, "seed"),
    case("plan-max-g-nan", [*P, "--sweep", "{c}/sweep_dir", "--max-g", "nan"], ERR, "max-g|sweep_dir"),
    case("plan-sweep-missing", [*P, "--sweep", "{c}/nope"], ERR, "nope"),
    case("plan-sweep-bad-json", [*P, "--sweep", "{c}/sweep_dir"], ERR, "sweep_dir"),
    case("plan-sweep-nan", [*P, "--sweep", "{c}/sweep_nan"], ANY, "sweep_nan"),
    case("plan-sweep-is-a-file", [*P, "--sweep", "{c}/a_file"], ERR, "a_file"),
    case("plan-stage-missing", ["plan", "{c}/nope.usda", "-o", "{out}"], ERR, "nope"),
    case("plan-stage-folder", ["plan", "{c}/a folder.usda", "-o", "{out}"], ERR, "a folder"),
    case("plan-stage-empty", ["plan", "{c}/empty.usda", "-o", "{out}"], ERR, "empty"),
    case("plan-stage-xodr", ["plan", "{c}/road ü.xodr", "-o", "{out}"], ERR, "road ü"),
    case("plan-output-under-a-file", [*P[:-1], "{c}/a_file/out"], ERR, "a_file"),
    case("plan-output-is-a-file", [*P[:-1], "{c}/a_file"], ERR, "a_file"),
]

D = ["reconstruct", "defects", "--transformed", "-o", "{out}", "--disparity"]
K = ["--K", "700,700,120,80", "--baseline", "0.12"]
RECON = [
    case("reconstruct-defects-ok-png", [*D, "{c}/disp.png"], OK),
    case("reconstruct-defects-ok-npy", [*D, "{c}/disp.npy"], OK),
    case("reconstruct-defects-ok-pair", ["reconstruct", "defects", "-o", "{out}", "--left", "{c}/left.png",
                                         "--right", "{c}/right.png", *K], OK),
    *[case(f"reconstruct-defects-{n.replace('.', '-')}", [*D, "{c}/" + n], ERR, re_name(n))
      for n in ("disp_truncated.png", "disp_header.png", "disp_text.png", "disp_empty.png", "disp_zero.png",
                "disp_1x1.png", "disp_3x2.png", "disp_row.png", "disp_rgb.png", "disp_allnan.npy",
                "disp_inf.npy", "disp_3d.npy", "disp_1d.npy", "disp_complex.npy", "disp_strings.npy",
                "disp_truncated.pfm", "disp_badheader.pfm", "disp.tiff", "a folder.png", "a folder.npy",
                "cloud.npz", "disp_bool.npy")],
    *[case(f"reconstruct-defects-{n.replace('.', '-')}", [*D, "{c}/" + n], ANY, re_name(n))
      for n in ("disp_const.png", "disp_neg.npy", "disp_partnan.npy", "disp_huge.npy", "disp.pfm")],
    case("reconstruct-defects-missing", [*D, "{c}/nope.png"], ERR, "nope"),
    case("reconstruct-defects-scale-zero", [*D, "{c}/disp.png", "--disparity-scale", "0"], ERR, "disparity.scale"),
    case("reconstruct-defects-scale-nan", [*D, "{c}/disp.png", "--disparity-scale", "nan"], ERR, "disparity.scale"),
    case("reconstruct-defects-grid-nan", [*D, "{c}/disp.png", "--grid", "nan"], ERR, "grid"),
    case("reconstruct-defects-untransformed-no-K", ["reconstruct", "defects", "-o", "{out}", "--disparity",
                                                    "{c}/disp.png"], ERR, "disp.png"),
    case("reconstruct-defects-K-nan", ["reconstruct", "defects", "-o", "{out}", "--disparity", "{c}/disp.png",
                                       "--K", "nan,700,120,80", "--baseline", "0.12"], ERR, "K"),
    case("reconstruct-defects-K-text", ["reconstruct", "defects", "-o", "{out}", "--disparity", "{c}/disp.png",
                                        "--K", "seven", "--baseline", "0.12"], ERR, "--K"),
    case("reconstruct-defects-K-three", ["reconstruct", "defects", "-o", "{out}", "--disparity", "{c}/disp.png",
                                         "--K", "1,2,3", "--baseline", "0.12"], ERR, "--K"),
    case("reconstruct-defects-baseline-nan", ["reconstruct", "defects", "-o", "{out}", "--disparity", "{c}/disp.png",
                                              "--K", "700,700,120,80", "--baseline", "nan"], ERR, "baseline"),
    case("reconstruct-defects-baseline-negative", ["reconstruct", "defects", "-o", "{out}", "--disparity",
                                                   "{c}/disp.png", "--K", "700,700,120,80", "--baseline", "-1"],
         ERR, "baseline"),
    case("reconstruct-defects-pair-sizes", ["reconstruct", "defects", "-o", "{out}", "--left", "{c}/left.png",
                                            "--right", "{c}/right_small.png", *K], ERR, "right_small"),
    case("reconstruct-defects-pair-truncated", ["reconstruct", "defects", "-o", "{out}", "--left", "{c}/left.png",
                                                "--right", "{c}/right_truncated.png", *K], ERR, "right_truncated"),
    case("reconstruct-defects-pair-folder", ["reconstruct", "defects", "-o", "{out}", "--left", "{c}/a folder.png",
                                             "--right", "{c}/right.png", *K], ERR, "a folder"),
    case("reconstruct-defects-left-only", ["reconstruct", "defects", "-o", "{out}", "--left", "{c}/left.png", *K],
         ERR, "right"),
    case("reconstruct-defects-nothing", ["reconstruct", "defects", "-o", "{out}"], ERR, "disparity"),
    case("reconstruct-defects-output-under-a-file", [*D[:3], "-o", "{c}/a_file/out", "--disparity", "{c}/disp.png"],
         ERR, "a_file"),
    case("reconstruct-defects-output-is-a-file", [*D[:3], "-o", "{c}/a_file", "--disparity", "{c}/disp.png"],
         ERR, "a_file"),
]
SF = ["reconstruct", "surface", "-o", "{out}.usda"]
RECON += [
    case("reconstruct-surface-ok-npy", [*SF, "{c}/cloud.npy"], OK),
    case("reconstruct-surface-ok-ply-kitti", [*SF, "{c}/cloud.ply", "--poses", "{c}/poses_kitti.txt"], OK),
    case("reconstruct-surface-ok-pcd-tum", [*SF, "{c}/cloud.pcd", "--poses", "{c}/poses_tum.txt"], OK),
    case("reconstruct-surface-ok-npz", [*SF, "{c}/cloud.npz"], OK),
    case("reconstruct-surface-ok-half-nan", [*SF, "{c}/half_nan.npy"], ANY, "half_nan"),
    *[case(f"reconstruct-surface-{n.replace('.', '-')}", [*SF, "{c}/" + n], ERR, re_name(n))
      for n in ("truncated.ply", "header_only.ply", "garbage.ply", "garbage.pcd", "all_nan.npy", "all_inf.npy",
                "huge.npy", "flat_2d.npy", "vector.npy", "three_points.npy", "empty.npy", "collinear.npy",
                "strings.npy", "objects.npy", "no_points.npz", "empty_archive.npz", "labels_mismatch.npz",
                "labels_none_road.npz", "truncated.npy", "truncated.npz", "cloud.las", "a folder.npy", "disp.png")],
    case("reconstruct-surface-missing", [*SF, "{c}/nope.npy"], ERR, "nope"),
    *[case(f"reconstruct-surface-{n.replace('.', '-')}", [*SF, "{c}/cloud.npy", "--poses", "{c}/" + n], ERR,
           re_name(n))
      for n in ("poses_two.txt", "poses_nan.txt", "poses_inf.txt", "poses_words.txt", "poses_seven.txt",
                "poses_zero_quat.txt", "poses_singular.txt", "poses_empty.txt", "a folder.npy")],
    case("reconstruct-surface-voxel-zero", [*SF, "{c}/cloud.npy", "--voxel", "0"], ERR, "voxel"),
    case("reconstruct-surface-voxel-nan", [*SF, "{c}/cloud.npy", "--voxel", "nan"], ERR, "voxel"),
    case("reconstruct-surface-radius-inf", [*SF, "{c}/cloud.npy", "--radius", "inf"], ERR, "radius"),
    case("reconstruct-surface-road-labels", [*SF, "{c}/cloud.npz", "--road-labels", "road"], ERR, "road-labels"),
    case("reconstruct-surface-road-labels-huge", [*SF, "{c}/cloud.npz", "--road-labels", "1e30"], ERR,
         "road-labels"),
    case("reconstruct-surface-masks-no-K", [*SF, "{c}/cloud.npy", "--masks", "{c}/disp.png"], ERR, "--K"),
    case("reconstruct-surface-masks-bad-extrinsic", [*SF, "{c}/cloud.npy", "--masks", "{c}/disp.png", "--K",
                                                     "500,500,60,40", "--cam-from-lidar", "{c}/extrinsic_nan.txt"],
         ERR, "extrinsic_nan"),
    case("reconstruct-surface-masks-short-extrinsic", [*SF, "{c}/cloud.npy", "--masks", "{c}/disp.png", "--K",
                                                       "500,500,60,40", "--cam-from-lidar",
                                                       "{c}/extrinsic_short.txt"], ERR, "extrinsic_short"),
    case("reconstruct-surface-masks-garbage", [*SF, "{c}/cloud.npy", "--masks", "{c}/disp_text.png", "--K",
                                               "500,500,60,40", "--cam-from-lidar", "{c}/poses_kitti.txt"],
         ERR, "disp_text|poses_kitti"),
    case("reconstruct-surface-output-not-usd", ["reconstruct", "surface", "-o", "{out}.ply", "{c}/cloud.npy"],
         ERR, "ply"),
    case("reconstruct-surface-output-under-a-file", ["reconstruct", "surface", "-o", "{c}/a_file/s.usda",
                                                     "{c}/cloud.npy"], ERR, "a_file"),
    case("reconstruct-surface-output-is-a-folder", ["reconstruct", "surface", "-o", "{c}/a folder.usda",
                                                    "{c}/cloud.npy"], ERR, "a folder"),
]


# --------------------------------------------------------------------------- the runner
def _digest(path: Path) -> str:
    h = hashlib.sha1()
    files = sorted(q for q in path.rglob("*") if q.is_file()) if path.is_dir() else [path]
    for q in files:
        h.update(str(q.relative_to(path) if path.is_dir() else q.name).encode())
        h.update(q.read_bytes())
    return h.hexdigest()


def _listing(folder: Path) -> set[str]:
    return {str(q.relative_to(folder)) for q in folder.rglob("*")}


@pytest.mark.parametrize("args, expect, names", [*IMPORT, *RENDER, *SWEEP, *PLAN, *RECON])
def test_hostile_input(corpus, tmp_path, capsys, monkeypatch, args, expect, names):
    import re

    c, town = corpus["c"], corpus["town"]
    outdir = tmp_path / "out ü"
    outdir.mkdir()
    out = outdir / "result"
    argv = [a.replace("{c}", str(c)).replace("{town}", str(town)).replace("{out}", str(out)) for a in args]
    inputs = [Path(a) for a in argv if a.startswith(str(c)) and Path(a).exists()]
    inputs += [town.parent] if str(town) in argv else []
    before = {p: _digest(p) for p in inputs}
    listing = _listing(c)

    code, stdout, stderr = run_main(argv, capsys, monkeypatch)

    text = stdout + stderr
    assert "Traceback" not in text and "internal error" not in text, text
    assert code in (0, 2), (code, text)
    assert {p: _digest(p) for p in inputs} == before, "an input changed"
    assert _listing(c) == listing, f"files appeared or vanished in the corpus: {_listing(c) ^ listing}"
    if code == 0:
        assert expect in (OK, ANY), f"expected a refusal naming {names!r}, got exit 0:\n{text}"
        assert any(outdir.iterdir()), "exit 0 but nothing written"
        assert not [q for q in outdir.iterdir() if q.name.startswith(".")], "temporary output left beside it"
    else:
        assert expect in (ERR, ANY), f"expected exit 0, got:\n{text}"
        lines = stderr.strip().splitlines()
        assert len(lines) == 1, stderr
        assert re.search(names, lines[0], re.IGNORECASE), f"the error does not name {names!r}: {lines[0]}"
        assert not list(outdir.iterdir()), f"partial output: {list(outdir.iterdir())}"
