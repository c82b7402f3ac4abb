"""``roadtwin reconstruct photos`` through the real command line: a labelled photo becomes a
library folder; bad input (an image without its label, a label of another size, a class map with
no defect class, a rig whose ray misses the road for a labelled pixel, a bad --rig) is one line on
stderr, exit 2, and no half-written library (an earlier one stays as it was).
The reconstruction itself: tests/plugins/test_photo_defects.py."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

import roadtwin_defects
import roadtwin_lookalikes
from cli_run import REPO, one_line, run_cli
from photo_scene import SURVEY, H, W, render_photo, save_pair
from roadtwin_core import PluginManager, RoadtwinError
from roadtwin_core.apps.reconstruct import PhotoInputs, check_photo_inputs
from roadtwin_core.apps.reconstruct.run import defect_types


@pytest.fixture(scope="module")
def scene():
    return render_photo(SURVEY)


@pytest.fixture
def photos(tmp_path, scene):
    save_pair(tmp_path / "p", "frame", *scene)
    return tmp_path / "p"


def test_cli_writes_a_library(photos, tmp_path):
    out = tmp_path / "lib"
    r = run_cli("reconstruct", "photos", photos / "images", "--labels", photos / "labels", "--classmap",
                "builtin:road_defects_br", "--rig", "survey", "-o", out)
    assert r.returncode == 0, r.stderr
    assert "1 asset(s) from 1 photo(s) (1 pothole)" in r.stdout
    assert (out / "frame_pothole_01.usda").exists() and (out / "textures/frame_pothole_01_diffuse.png").exists()


def test_image_without_label(photos, tmp_path):
    cv2.imwrite(str(photos / "images" / "lonely.png"), np.zeros((H, W, 3), np.uint8))
    out = tmp_path / "lib"
    one_line(run_cli("reconstruct", "photos", photos / "images", "--labels", photos / "labels", "-o", out),
             "lonely.png", "no label")
    assert not out.exists()


def test_label_of_another_size(photos, tmp_path):
    cv2.imwrite(str(photos / "labels/frame.png"), np.ones((320, 512), np.uint8) * 3)
    out = tmp_path / "lib"
    one_line(run_cli("reconstruct", "photos", photos / "images", "--labels", photos / "labels", "-o", out),
             "512x320", "1024x640")
    assert not out.exists()


def test_class_map_without_defect_class(photos, tmp_path):
    cm = tmp_path / "lanes.toml"
    cm.write_text('name = "lanes"\nclasses = ["background", "lane"]\nunknown = "background"\n'
                  '[map]\nlane = ["driving"]\n')
    out = tmp_path / "lib"
    one_line(run_cli("reconstruct", "photos", photos / "images", "--labels", photos / "labels", "--classmap", cm,
                     "-o", out), "no defect class")
    assert not out.exists()


def test_rig_whose_ray_misses_the_road(photos, tmp_path):
    lab = cv2.imread(str(photos / "labels/frame.png"), cv2.IMREAD_UNCHANGED)
    lab[5:15, 500:520] = 3                              # a pothole label near the top of the frame
    cv2.imwrite(str(photos / "labels/frame.png"), lab)
    out = tmp_path / "lib"
    out.mkdir()
    (out / "keep.txt").write_text("earlier output")
    # a level camera: the top half of the frame is sky
    err = one_line(run_cli("reconstruct", "photos", photos / "images", "--labels", photos / "labels",
                           "--rig", "survey:pitch=0", "-o", out), "misses the road", "pitch 0")
    assert "frame.png" in err
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"] and (out / "keep.txt").read_text() == "earlier output"


def test_bad_rig_is_one_line(photos, tmp_path):
    one_line(run_cli("reconstruct", "photos", photos / "images", "--labels", photos / "labels", "--rig",
                     "survey:pitch", "-o", tmp_path / "lib"), "--rig", "key=number")


@pytest.mark.parametrize("rig, overrides, needle", [
    ("nope", {}, "no rig preset 'nope'"), ("survey", {"tilt": 1.0}, "unknown key 'tilt'"),
    ("survey", {"height": -1.0}, "height above the road"), ("survey", {"hfov": 200.0}, "hfov"),
    ("survey", {"width": 10.5}, "number of pixels")])
def test_rig_bounds_are_checked_in_the_app(photos, rig, overrides, needle):
    with pytest.raises(RoadtwinError, match=needle):
        check_photo_inputs(PhotoInputs([photos / "images"], photos / "labels", rig=rig, rig_overrides=overrides),
                           {"pothole", "crack"})


def test_look_alikes_are_not_defect_classes(photos):
    """road_defects_br maps look-alike types (oil_stain, ...) to background and the ego lane: they
    must not make those classes defect classes (only pothole and crack are)."""
    pm = PluginManager(load_entry_points=False)
    pm.register(roadtwin_defects, name="defects")
    pm.register(roadtwin_lookalikes, name="lookalikes")
    types = defect_types(pm)
    lookalikes = {cls.name for cls in roadtwin_lookalikes.ALL}
    assert {"pothole", "crack", "patch"} <= types and lookalikes <= set(pm.registry("defect_types"))
    assert not types & lookalikes
    got = check_photo_inputs(PhotoInputs([photos / "images"], photos / "labels"), types)
    assert got.classes == {2: ("crack", "crack"), 3: ("pothole", "pothole")}
    assert got.rig["name"] == "survey" and got.rig["pitch_deg"] == SURVEY.pitch_deg and len(got.images) == 1


REAL = REPO.parent / "shared/data/road_defects_br/train_full"
# two train frames: cracks that touch at texel corners (the second), and assets to write (the first)
REAL_FRAMES = [REAL / "images" / f"{stem}.jpg" for stem in ("1075621_DF_251_251BDF0530_02002",
                                                              "1075627_DF_251_251BDF0530_02013")]


@pytest.mark.skipif(not all(f.is_file() for f in REAL_FRAMES),
                    reason="../shared/data/road_defects_br/train_full is not beside the repository")
def test_real_crack_frames_reconstruct_with_nothing_on_stderr(tmp_path):
    """What a user sees of a good run is the summary: no numpy warning from the cracks' outlines."""
    r = run_cli("reconstruct", "photos", *REAL_FRAMES, "--labels", REAL / "labels", "-o", tmp_path / "lib")
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and "crack" in r.stdout, r.stderr


def test_a_class_filled_from_several_types_is_named_by_its_own_type_else_the_first():
    """road_defects_br fills crack from crack and alligator, pothole from pothole and ravelling: a
    photo's labelled crack is a crack asset (the type named like the class), whatever the order or
    alphabet; a class no type is named like takes the first type in the map's order."""
    from roadtwin_core.apps.reconstruct.inputs import defect_classes
    from roadtwin_core.render.classmap import ClassMap

    types = {"alligator", "crack", "pothole", "ravelling", "rut", "depression"}
    cmap = ClassMap("t", ("background", "crack", "pothole", "dent"),
                    {"alligator": "crack", "crack": "crack", "ravelling": "pothole", "pothole": "pothole",
                     "rut": "dent", "depression": "dent"}, {}, "background")
    assert defect_classes(cmap, types) == {1: ("crack", "crack"), 2: ("pothole", "pothole"), 3: ("dent", "rut")}
