"""Dataset writing of ``roadtwin render`` with a fake renderer (``tests/fakes.py``): no warp, no
ray tracing. The fake sees the plane z = 0; the files written must hold what that plane looks
like from the poses ``meta.json`` reports, computed here per pixel from the pinhole model."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import triangle

from roadtwin_core import ComposeRules, RoadSegment, TownLayout

from fakes import GROUND, SKY, FakeRenderer, fake_plugin_manager


def _flat_road() -> TownLayout:
    poly = np.array([[0.0, -3.5], [40.0, -3.5], [40.0, 3.5], [0.0, 3.5]])
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "pqa8")
    seg = RoadSegment("r0", "driving", t["vertices"], t["triangles"], np.array([[0.0, 0.0], [40.0, 0.0]]))
    return TownLayout("Town", [seg], ComposeRules(defect_count=0, seed=1, surface="flat"))


def _plane_depth(k: dict, cam_to_world: np.ndarray) -> np.ndarray:
    """z-depth of the plane z = 0 per pixel: the camera-frame ray (x, y, 1) scaled to reach z = 0."""
    u, v = np.meshgrid(np.arange(k["width"]), np.arange(k["height"]))
    ray_cam = np.stack([(u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"], np.ones(u.shape)], -1)
    rz = ray_cam @ cam_to_world[2, :3]              # world z component of each ray (camera z = 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -cam_to_world[2, 3] / rz
    return np.where(np.isfinite(s) & (s > 0), s, 0.0)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    from roadtwin_core.apps.render import RenderOptions, run_render
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.usd import write_layout

    base = tmp_path_factory.mktemp("fake")
    write_layout(_flat_road(), base / "road.usda")
    town = compose(base / "road.usda", base / "town", preview=False, executor="serial").town
    renderer = FakeRenderer()
    out = base / "out"
    run_render(town, out, RenderOptions(renderer="fake", frames=3, size="48x32", stereo=True, baseline=0.5, height=1.6,
                                        pitch=-20.0, formats="kitti,depth,mmseg", executor="serial", seed=2),
               pm=fake_plugin_manager(renderer=renderer))
    return out, renderer


def test_fake_renderer_frames_are_written_where_meta_says(dataset):
    out, renderer = dataset
    meta = json.loads((out / "meta.json").read_text())
    k = meta["intrinsics"]
    assert renderer.frames == len(meta["frames"]) == 3
    classes = [c["name"] for c in meta["classes"]]
    for fr in meta["frames"]:
        expected = _plane_depth(k, np.array(fr["cam_to_world"]))
        hit = expected > 0
        assert 0 < hit.mean() < 1                                   # road and sky in every frame
        depth = np.load(out / fr["files"]["depth"])
        np.testing.assert_allclose(depth, expected, rtol=1e-5, atol=1e-5)
        labels = cv2.imread(str(out / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
        assert (labels == np.where(hit, classes.index("driving"), 0)).all()
        disp = cv2.imread(str(out / fr["files"]["disparity"]), cv2.IMREAD_UNCHANGED).astype(float)
        with np.errstate(divide="ignore"):
            want = np.where(hit, np.clip(np.rint(k["fx"] * 0.5 / np.where(hit, expected, 1) * 256), 1, 65535), 0)
        assert np.abs(disp - want).max() <= 1                       # KITTI: disparity * 256
        rgb = cv2.imread(str(out / fr["files"]["rgb"]), cv2.IMREAD_UNCHANGED)
        road_px, sky_px = rgb[hit].astype(float), rgb[~hit].astype(float)
        assert road_px.std() == 0 and sky_px.std() == 0 and road_px.mean() < sky_px.mean()   # GROUND < SKY
    calib = (out / meta["frames"][0]["files"]["kitti_left"]).parent.parent / "calib_cam_to_cam"
    p3 = next(line for line in (calib / "000000.txt").read_text().splitlines() if line.startswith("P_rect_03"))
    assert float(p3.split()[4]) == pytest.approx(-k["fx"] * 0.5)   # P_rect_03[0, 3] = -fx * B
    assert GROUND < SKY
