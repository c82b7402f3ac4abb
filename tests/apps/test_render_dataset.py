"""``roadtwin render`` as a perception-data tool: rigs, the defect view sampler, class maps with
the ego lane, randomization, executors and camera prims, checked against references computed
here without the renderer (flat road: every pixel's world point is a ray-plane intersection;
defect footprints from the library assets and their placements; markings painted by hand).

One small two-lane road (80 m, lanes, shoulders, verges, potholes and cracks, a painted centre
line) is composed per module; frames are tiny (at most 160x100).
"""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import types
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import triangle

import roadtwin_core
import roadtwin_defects
import roadtwin_warp_render
from roadtwin_core import ComposeRules, PluginManager, RoadSegment, RoadtwinError, TownLayout
from roadtwin_core.apps.render import RenderOptions, parse_views, run_render
from roadtwin_core.render import Camera, Intrinsics, RenderMesh, look_from
from roadtwin_core.render.cameras import RIG_PRESETS

LANE_W, MARK_HALF_W, LENGTH = 3.5, 0.075, 80.0


# --------------------------------------------------------------------------- the small road
def _strip(name, kind, x0, x1, y0, y1, centerline=None) -> RoadSegment:
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "pqa4")
    return RoadSegment(name, kind, t["vertices"], t["triangles"], centerline)


def _layout() -> TownLayout:
    segs = []
    for i, x in enumerate(np.arange(0.0, LENGTH, 20.0)):
        x1 = x + 20.0
        segs += [_strip(f"r{i}", "driving", x, x1, -LANE_W, 0.0, np.array([[x, -LANE_W / 2], [x1, -LANE_W / 2]])),
                 _strip(f"l{i}", "driving", x, x1, 0.0, LANE_W, np.array([[x1, LANE_W / 2], [x, LANE_W / 2]])),
                 _strip(f"sr{i}", "shoulder", x, x1, -LANE_W - 2.0, -LANE_W),
                 _strip(f"sl{i}", "shoulder", x, x1, LANE_W, LANE_W + 2.0),
                 _strip(f"vr{i}", "verge", x, x1, -LANE_W - 6.0, -LANE_W - 2.0),
                 _strip(f"vl{i}", "verge", x, x1, LANE_W + 2.0, LANE_W + 6.0)]
    rules = ComposeRules(defect_count=14, seed=5, surface="flat", models_per_type=2,
                         type_weights={"pothole": 3.0, "crack": 2.0}, edge_margin_m=0.5)
    return TownLayout("Town", segs, rules)


def _paint_centre_line(town: Path) -> None:
    """A white centre line (0.15 m, 3 mm proud of the road) in a sublayer, as a markings layer
    writes it: ``/Town/Markings/centre`` with ``roadtwin:marking:type``."""
    from pxr import Sdf, Usd, UsdGeom

    from roadtwin_core.usd.stage import write_mesh

    path = town.parent / "layers/test_markings.usda"
    st = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(st, UsdGeom.Tokens.z)
    group = UsdGeom.Xform.Define(st, "/Town/Markings/centre")
    group.GetPrim().CreateAttribute("roadtwin:marking:type", Sdf.ValueTypeNames.String).Set("solid")
    xs = np.linspace(0.0, LENGTH, 33)
    v = np.array([(x, y, 0.003) for x in xs for y in (-MARK_HALF_W, MARK_HALF_W)])
    f = [(2 * i, 2 * i + 2, 2 * i + 1) for i in range(len(xs) - 1)] + \
        [(2 * i + 1, 2 * i + 2, 2 * i + 3) for i in range(len(xs) - 1)]
    write_mesh(UsdGeom.Mesh.Define(st, "/Town/Markings/centre/paint"), v, np.array(f))
    st.GetRootLayer().Save()
    root = Sdf.Layer.FindOrOpen(str(town))
    root.subLayerPaths.insert(0, "./layers/test_markings.usda")
    root.Save()


@pytest.fixture(scope="module")
def pm():
    m = PluginManager(load_entry_points=False)
    m.register(roadtwin_defects, name="defects")
    m.register(roadtwin_warp_render, name="warp_render")
    return m


@pytest.fixture(scope="module")
def road(tmp_path_factory, pm):
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.usd import write_layout

    base = tmp_path_factory.mktemp("road")
    write_layout(_layout(), base / "road.usda")
    town = compose(base / "road.usda", base / "town", preview=False, executor="serial").town
    _paint_centre_line(town)
    return town


@pytest.fixture(scope="module")
def dataset(road, pm, tmp_path_factory):
    """8 survey frames, half aimed at a pothole or crack, randomized, class-mapped."""
    out = tmp_path_factory.mktemp("ds") / "out"
    summary = run_render(road, out, RenderOptions(frames=8, rig="survey", size="160x100", views="defects:0.5",
                                                  randomize=True, classmap="builtin:road_defects_br",
                                                  formats="mmseg,coco", executor="serial", seed=3), pm=pm)
    return out, summary


def _ground_points(cam: Camera, z: float = 0.0) -> np.ndarray:
    """World XY where each pixel centre's ray meets the plane at height z (NaN: never)."""
    d, o = cam.rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (z - o[2]) / d[..., 2]
    t = np.where(t > 0, t, np.nan)
    return o[:2] + d[..., :2] * t[..., None]


def _frames(out: Path):
    meta = json.loads((out / "meta.json").read_text())
    k = meta["intrinsics"]
    intr = Intrinsics(k["width"], k["height"], k["fx"], k["fy"], k["cx"], k["cy"])
    for fr in meta["frames"]:
        labels = cv2.imread(str(out / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
        inst = cv2.imread(str(out / fr["files"]["instance"]), cv2.IMREAD_UNCHANGED)
        yield meta, fr, Camera(intr, np.array(fr["cam_to_world"])), labels, inst


def _band(mask: np.ndarray) -> np.ndarray:
    """Pixels within 1 px of the mask's boundary (where pixel-centre sampling may differ)."""
    k = np.ones((3, 3), np.uint8)
    m = mask.astype(np.uint8)
    return (cv2.dilate(m, k) > 0) & ~(cv2.erode(m, k) > 0)


# --------------------------------------------------------------------------- labels vs geometry
def test_pothole_pixels_lie_inside_their_projected_footprints(dataset, road):
    from roadtwin_core.model import Placement
    from roadtwin_core.usd.library import read_defect_asset
    from roadtwin_core.usd.town_reader import load_town

    out, _ = dataset
    town = load_town(road)
    footprints = []
    for d in town.defects:
        model = read_defect_asset(road.parent / "library" / f"{d.attributes['model']}.usda")
        x, y, yaw = d.attributes["poseXYYaw"]
        footprints.append(Placement(d.id, model, x, y, yaw, tuple(d.attributes["scale"])).world_footprint())
    seen = 0
    for meta, fr, cam, labels, inst in _frames(out):
        pothole = labels == 3
        assert set(np.unique(labels)) <= {0, 1, 2, 3, 255}
        for iid in np.unique(inst[pothole]):
            assert iid > 0, "a pothole pixel without a defect instance"
            info = meta["instances"][iid - 1]
            assert info["type"] == "pothole"
            poly = footprints[iid - 1]
            uv, z = cam.project(np.column_stack([poly, np.zeros(len(poly))]))
            assert (z > 0).all()
            mask = np.zeros(labels.shape, np.uint8)
            cv2.fillPoly(mask, [np.rint(uv * 16).astype(np.int32)], 1, shift=4)
            mask = cv2.dilate(mask, np.ones((3, 3), np.uint8)) > 0        # 1 px of rasterization slack
            mine = pothole & (inst == iid)
            assert mine[~mask].sum() == 0, f"frame {fr['index']}: pothole pixels outside defect {iid}'s footprint"
            seen += int(mine.sum())
    assert seen > 50                                                   # the frames do show potholes


def test_markings_are_labelled_where_painted_and_ego_lane_follows_the_lane(dataset):
    out, _ = dataset
    painted_px = ego_px = 0
    for meta, fr, cam, labels, inst in _frames(out):
        valid = labels != 255
        xy = _ground_points(cam, 0.003)
        on_road = np.isfinite(xy[..., 0]) & (xy[..., 0] > 0.5) & (xy[..., 0] < LENGTH - 0.5)
        painted = on_road & (np.abs(xy[..., 1]) <= MARK_HALF_W)
        defect = labels >= 2
        # the line is inside the ego lane's `from` labels only within the ego lane; outside it
        # a marking maps to background. Check it through the roadtwin class instead: the pixel
        # is a marking exactly where painted (the class map's ego side is checked below).
        forward = cam.cam_to_world[0, 2] > 0
        centre = -LANE_W / 2 if forward else LANE_W / 2
        xy0 = _ground_points(cam, 0.0)
        in_lane = on_road & (np.abs(xy0[..., 1] - centre) <= LANE_W / 2)
        ego = labels == 1
        # ego lane pixels lie in the camera's lane (1 px of slack at its edges and at defects)
        stray = ego & ~in_lane & ~_band(in_lane)
        assert stray.sum() == 0, f"frame {fr['index']}: {stray.sum()} ego-lane pixels outside the lane"
        # ... and cover it, except defects (they win) and far pixels (ignore)
        inner = in_lane & ~_band(in_lane) & valid & ~cv2.dilate(defect.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert ego[inner].mean() > 0.99
        ego_px += int(ego.sum())
        # the painted line inside the ego lane is ego lane (a marking is road surface)
        painted_px += int((painted & in_lane & valid).sum())
        assert (ego | defect | ~valid | _band(painted))[painted & in_lane].all()
    assert ego_px > 1000 and painted_px > 0


def test_markings_get_their_class_in_roadtwin_labels(road, pm, tmp_path):
    """Without a class map the labels are roadtwin's: lane_marking exactly where the line is
    painted (pixel centres), up to 1 px at its edges."""
    out = tmp_path / "raw"
    run_render(road, out, RenderOptions(frames=3, rig="survey", size="160x100", views="defects:0", formats="mmseg",
                                        executor="serial", seed=1), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    mark = [c["id"] for c in meta["classes"] if c["name"] == "lane_marking"][0]
    k = meta["intrinsics"]
    intr = Intrinsics(k["width"], k["height"], k["fx"], k["fy"], k["cx"], k["cy"])
    total = 0
    for fr in meta["frames"]:
        labels = cv2.imread(str(out / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
        cam = Camera(intr, np.array(fr["cam_to_world"]))
        xy = _ground_points(cam, 0.003)
        painted = np.isfinite(xy[..., 0]) & (np.abs(xy[..., 1]) <= MARK_HALF_W) & (xy[..., 0] > 0) & (xy[..., 0] < LENGTH)
        got = labels == mark
        wrong = (got != painted) & ~_band(painted) & (labels != 255)
        assert wrong.sum() == 0
        total += int(got.sum())
    assert total > 0


# --------------------------------------------------------------------------- sampler, summary
def test_view_share_through_the_command_and_targets_in_view(dataset, road):
    from roadtwin_core.usd.town_reader import load_town

    out, summary = dataset
    meta = json.loads((out / "meta.json").read_text())
    targeted = [f for f in meta["frames"] if f["view"]["target"] is not None]
    assert len(targeted) == 4                                            # defects:0.5 of 8 frames
    ids = {i["defect_id"]: i["id"] for i in meta["instances"]}
    pose = {d.id: d.attributes["poseXYYaw"] for d in load_town(road).defects}
    k = meta["intrinsics"]
    intr = Intrinsics(k["width"], k["height"], k["fx"], k["fy"], k["cx"], k["cy"])
    shown = 0
    for f in targeted:
        # the aimed-at defect's centre projects into the image, 5-25 m ahead
        x, y, _ = pose[f["view"]["target"]]
        uv, z = Camera(intr, np.array(f["cam_to_world"])).project(np.array([[x, y, 0.0]]))
        assert 0 <= uv[0, 0] < k["width"] and 0 <= uv[0, 1] < k["height"] and 4.0 < z[0] < 26.0
        inst = cv2.imread(str(out / f["files"]["instance"]), cv2.IMREAD_UNCHANGED)
        shown += int((inst == ids[f["view"]["target"]]).sum() > 0)   # far ones may fall between rows at 160x100
    assert shown >= 1
    # the summary's defect statistics are those of the written labels
    shares = []
    for f in meta["frames"]:
        lab = cv2.imread(str(out / f["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
        shares.append(((lab == 3).mean(), (lab == 2).mean()))
    shares = np.array(shares)
    st = summary["defects"]
    assert st["pothole"]["frames_with"] == pytest.approx((shares[:, 0] > 0).mean())
    assert st["crack"]["mean_pixel_share"] == pytest.approx(shares[:, 1].mean(), abs=1e-6)
    assert summary["size"] == [160, 100] and summary["rig"] == "survey" and summary["randomize"]
    assert meta["classes"] == [{"id": i, "name": n} for i, n in enumerate(("background", "ego_lane", "crack", "pothole"))]
    # randomization records and JPEG images straight from the sensor model
    r = meta["frames"][0]["randomization"]
    assert {"render", "look", "effects", "applied"} <= set(r)
    assert (out / meta["frames"][0]["files"]["rgb"]).read_bytes()[:2] == b"\xff\xd8"
    assert (out / "mmseg/img_dir/train/000000.jpg").exists()


def test_views_aim_at_defects_within_the_asked_distance(road, pm, tmp_path):
    """``defects:1:2.5-8``: every frame's target lies 2.5-8 m ahead in plan (a survey's measured
    defect distances), against the defect's pose and the camera, not the sampler's own record."""
    from roadtwin_core.usd.town_reader import load_town

    out = tmp_path / "near"
    run_render(road, out, RenderOptions(frames=6, rig="survey", size="64x40", views="defects:1:2.5-8", formats="mmseg",
                                        executor="serial"), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["render"]["poses"] == "defects:1.0:2.5-8"
    pose = {d.id: d.attributes["poseXYYaw"] for d in load_town(road).defects}
    for f in meta["frames"]:
        c2w = np.array(f["cam_to_world"])
        heading = c2w[:2, 2] / np.linalg.norm(c2w[:2, 2])          # the optical axis in plan
        x, y, _ = pose[f["view"]["target"]]
        ahead = float(np.dot(np.array([x, y]) - c2w[:2, 3], heading))
        assert 2.5 - 1e-6 <= ahead <= 8.0 + 1e-6


def test_label_range_leaves_far_defects_unlabelled(road, pm, tmp_path):
    """A class map's [label_range_m] (how far ahead a survey's annotators labelled): no pothole
    label deeper than its range in the written labels, read against the written depth, and the
    far ones are ignore, not road."""
    from importlib import resources

    text = resources.files("roadtwin_core.render").joinpath("classmaps", "road_defects_br.toml").read_text()
    cmap = tmp_path / "near.toml"
    cmap.write_text(text + "\n[label_range_m]\ncrack = 8.5\npothole = 9.0\n")
    out = tmp_path / "near"
    run_render(road, out, RenderOptions(frames=6, rig="survey", size="160x100", views="defects:1:5-25", classmap=str(cmap),
                                        formats="mmseg,depth", executor="serial", seed=2), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    far_ignored = 0
    for f in meta["frames"]:
        lab = cv2.imread(str(out / f["files"]["semantic"]), cv2.IMREAD_UNCHANGED)
        depth = np.load(out / f["files"]["depth"])
        assert not ((lab == 3) & (depth > 9.0)).any()
        far_ignored += int(((lab == 255) & (depth > 9.0)).sum())
    assert far_ignored > 0


def test_parse_views():
    assert tuple(parse_views("random")[:3]) == ("random", None, "uniform")
    assert tuple(parse_views("defects:0.6")) == ("defects", 0.6, "uniform", (5.0, 25.0))
    assert tuple(parse_views("defects:1:clear")[:3]) == ("defects", 1.0, "clear")
    assert parse_views("defects:0.8:clear:2.5-12").distance_m == (2.5, 12.0)
    assert parse_views("defects:0.8:3-9").distance_m == (3.0, 9.0)
    for bad in ("defects", "defects:1.5", "defects:0.5:sometimes", "all", "defects:0.5:clear:12-3", "defects:0.5:4-4", "defects:0.5:1-5000"):
        with pytest.raises(RoadtwinError, match="--views"):
            parse_views(bad)


# --------------------------------------------------------------------------- executors
def render_on(executors, road, pm, tmp_path) -> dict:
    """The same 4 randomized survey frames rendered on each executor: {name: output folder}."""
    outs = {}
    for name in executors:
        outs[name] = tmp_path / name
        run_render(road, outs[name], RenderOptions(frames=4, rig="survey", size="64x40", views="defects:0.5",
                                                   randomize=True, classmap="builtin:road_defects_br",
                                                   formats="mmseg", executor=name, workers=2, seed=9), pm=pm)
    return outs


def assert_same_dataset(a_root, b_root) -> list:
    """Two render outputs hold the same files, byte for byte, but meta.json, whose frame records
    must be equal (its timings differ run to run); returns the files (relative paths)."""
    files = sorted(p.relative_to(a_root) for p in a_root.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b_root) for p in b_root.rglob("*") if p.is_file())
    for f in files:
        a, b = a_root / f, b_root / f
        if f.name == "meta.json":
            assert json.loads(a.read_text())["frames"] == json.loads(b.read_text())["frames"]
        else:
            assert a.read_bytes() == b.read_bytes(), f
    return files


def test_serial_and_local_executors_write_the_same_bytes(road, pm, tmp_path):
    outs = render_on(("local", "serial"), road, pm, tmp_path)
    assert_same_dataset(outs["serial"], outs["local"])


@pytest.mark.slow
def test_ray_executor_writes_the_same_bytes_as_serial(road, pm, tmp_path):
    """Issue 21: frames spread over a (local) Ray cluster are the frames of one process."""
    pytest.importorskip("ray")
    outs = render_on(("serial", "ray"), road, pm, tmp_path)
    files = sorted(p.relative_to(outs["serial"]) for p in outs["serial"].rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(outs["ray"]) for p in outs["ray"].rglob("*") if p.is_file())
    images = [f for f in files if f.suffix in (".png", ".jpg")]
    assert len(images) >= 8                              # 4 frames: images and labels
    for f in files:
        if f.name != "meta.json":
            assert (outs["ray"] / f).read_bytes() == (outs["serial"] / f).read_bytes(), f


# --------------------------------------------------------------------------- rig cameras
def test_rig_cameras_round_trip_and_render_like_a_poses_file(road, pm, tmp_path):
    from pxr import Gf, Usd, UsdGeom

    from roadtwin_core.render.rig_usd import add_rig_cameras, read_stage_cameras

    stage_dir = tmp_path / "town"
    shutil.copytree(road.parent, stage_dir)
    stage = stage_dir / road.name
    add_rig_cameras(stage, ["survey", "dashcam"], at_s=30.0)
    cams = {c.rig: c for c in read_stage_cameras(stage)}
    usd = Usd.Stage.Open(str(stage))
    for name in ("survey", "dashcam"):
        p = RIG_PRESETS[name]
        ref = Intrinsics.from_fov(p.width, p.height, p.hfov_deg)
        k = cams[name].intrinsics
        assert (k.width, k.height) == (p.width, p.height)
        assert k.fx == pytest.approx(ref.fx, rel=1e-6) and k.fy == pytest.approx(ref.fy, rel=1e-6)
        prim = UsdGeom.Camera(usd.GetPrimAtPath(cams[name].path))
        gf = prim.GetCamera(Usd.TimeCode.Default())
        assert gf.GetFieldOfView(Gf.Camera.FOVHorizontal) == pytest.approx(p.hfov_deg, abs=1e-4)
        # tenths of a scene unit on a metre stage: a 36 mm filmback is 0.36
        assert prim.GetHorizontalApertureAttr().Get() == pytest.approx(0.36)
        # pose: the rig's height above the (flat) road and its pitch, looking along the lane
        m = cams[name].cam_to_world
        assert m[2, 3] == pytest.approx(p.height_m, abs=1e-4)
        assert math.degrees(math.asin(m[2, 2])) == pytest.approx(p.pitch_deg, abs=1e-3)
        # USD's view direction (-Z of the prim) is the OpenCV camera's +z
        fwd = np.array(prim.ComputeLocalToWorldTransform(Usd.TimeCode.Default()).TransformDir(Gf.Vec3d(0, 0, -1)))
        np.testing.assert_allclose(fwd / np.linalg.norm(fwd), m[:3, 2], atol=1e-6)
    # the stage's survey camera renders exactly like the same pose from a poses file
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps([{"cam_to_world": cams["survey"].cam_to_world.tolist()}]))
    a, b = tmp_path / "a", tmp_path / "b"
    s = run_render(stage, a, RenderOptions(rig="survey", size="128x80", formats="mmseg", executor="serial"), pm=pm)
    assert s["poses"] == "stage cameras" and s["frames"] == 1
    run_render(stage, b, RenderOptions(rig="survey", size="128x80", poses=poses, formats="mmseg",
                                       executor="serial"), pm=pm)
    for sub in ("images/000000.png", "mmseg/ann_dir/train/000000.png"):
        assert (a / sub).read_bytes() == (b / sub).read_bytes()
    # several rigs of different sizes: pick one
    with pytest.raises(RoadtwinError, match="--rig"):
        run_render(stage, tmp_path / "c", RenderOptions(formats="mmseg", executor="serial"), pm=pm)


# --------------------------------------------------------------------------- scene looks
def test_verge_remap_and_road_tint_in_the_renderer(pm, tmp_path):
    """A verge switched to a red 'gravel' texture from textures/ turns red; the road beside it
    keeps its colour; a road tint scales the road's diffuse light."""
    from PIL import Image

    from roadtwin_core.render import build_render_mesh, RenderParams
    from roadtwin_core.render.randomize import SceneLook
    from roadtwin_core.render.scene_look import LookTable
    from roadtwin_core.usd.town_reader import TownMesh, TownScene

    (tmp_path / "textures").mkdir()
    Image.fromarray(np.full((4, 4, 3), (200, 20, 20), np.uint8)).save(tmp_path / "textures/gravel_diffuse.png")
    road = _strip("r", "driving", 0, 40, -2, 0)
    verge = _strip("v", "verge", 0, 40, 0, 4)
    town = TownScene("T", "t", roads=[TownMesh("r", "driving", road.vertices, road.faces),
                                      TownMesh("v", "verge", verge.vertices, verge.faces)])
    mesh, table = LookTable.split(build_render_mesh(town), tmp_path, ("gravel", "soil"))
    assert "gravel" in table.variants and "soil" not in table.variants
    rend = pm.get("renderers", "warp")
    cam = Camera(Intrinsics.from_fov(64, 40, 60.0), look_from((2.0, 0.0, 2.0), 0.0, math.radians(-35)))
    params = RenderParams(shadows=False)
    plain = next(rend.render(mesh, [cam], params, look=table.identity()))
    gravel = next(rend.render(mesh, [cam], params, look=table.look(SceneLook(verge_surface="gravel"))))
    tinted = next(rend.render(mesh, [cam], params, look=table.look(SceneLook(road_tint=(1.2, 1.0, 0.8)))))
    cls = plain.semantic
    v, r = cls == mesh.classes.index("verge"), cls == mesh.classes.index("driving")
    assert v.sum() > 50 and r.sum() > 50
    red = gravel.rgb[v]
    assert (red[:, 0] > 3 * red[:, 1]).all() and np.allclose(plain.rgb[v][:, 0], plain.rgb[v][:, 1], rtol=0.05)
    np.testing.assert_array_equal(gravel.rgb[r], plain.rgb[r])
    ratio = tinted.rgb[r].mean(axis=0) / plain.rgb[r].mean(axis=0)
    assert ratio[0] > 1.1 and ratio[2] < 0.9 and abs(ratio[1] - 1.0) < 0.02
    np.testing.assert_array_equal(tinted.rgb[v], plain.rgb[v])


def test_pothole_look_scales_only_the_pothole_interior(tmp_path):
    """A frame's pothole albedo multiplies the pothole material (and nothing else); the wet
    interior is swapped in when the stage's textures/ has it."""
    from PIL import Image

    from roadtwin_core.render import RenderMaterial, build_render_mesh
    from roadtwin_core.render.randomize import SceneLook
    from roadtwin_core.render.scene_look import LookTable
    from roadtwin_core.usd.town_reader import TownMesh, TownScene

    road = _strip("r", "driving", 0, 10, -2, 0)
    hole = _strip("h", "driving", 2, 3, -1, -0.5)
    grey = np.full((1, 1, 3), 0.2, np.float32)
    mesh = build_render_mesh(TownScene("T", "t", roads=[TownMesh("r", "driving", road.vertices, road.faces),
                                                        TownMesh("h", "driving", hole.vertices, hole.faces)]))
    # bind the second strip to a material named like the catalog's pothole interior
    mats = list(mesh.materials) + [RenderMaterial("/T/Looks/pothole", grey, np.full((1, 1, 1), 0.9, np.float32), None)]
    fm = mesh.face_material.copy()
    fm[len(road.faces):] = len(mats) - 1
    mesh = type(mesh)(mesh.vertices, mesh.faces, mesh.face_class, mesh.face_instance, fm, mesh.face_uv, mesh.classes,
                      mats, mesh.instances, mesh.defect_types, mesh.source)
    (tmp_path / "textures").mkdir()
    Image.fromarray(np.full((2, 2, 3), 10, np.uint8)).save(tmp_path / "textures/pothole_wet_diffuse.png")
    mesh, table = LookTable.split(mesh, tmp_path, ("pothole_wet",))
    hole_ids = np.unique(mesh.face_material[len(road.faces):])
    road_ids = np.unique(mesh.face_material[:len(road.faces)])
    look = table.look(SceneLook(pothole_albedo=(2.0, 1.5, 1.0)))
    np.testing.assert_allclose(look.albedo_scale[hole_ids], [[2.0, 1.5, 1.0]] * len(hole_ids))
    np.testing.assert_allclose(look.albedo_scale[road_ids], 1.0)
    wet = table.look(SceneLook(pothole_surface="pothole_wet"))
    assert (wet.remap[hole_ids] == table.variants["pothole_wet"]).all()
    assert (wet.remap[road_ids] == road_ids).all()


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("kwargs, message", [
    ({"rig": "drone"}, "unknown rig 'drone'"),
    ({"views": "defects:2"}, "--views must be"),
    ({"views": "targets"}, "--views must be"),
    ({"classmap": "missing.toml"}, "missing.toml: no such class map file"),
    ({"views": "random", "poses": "p.json"}, "not both"),
])
def test_bad_options_are_one_line(road, pm, tmp_path, kwargs, message):
    with pytest.raises(RoadtwinError, match=message) as err:
        run_render(road, tmp_path / "out", RenderOptions(frames=1, size="16x12", executor="serial", **kwargs), pm=pm)
    assert "\n" not in str(err.value) and not (tmp_path / "out").exists()


def test_class_map_naming_a_label_the_stage_lacks(road, pm, tmp_path):
    bad = tmp_path / "mine.toml"
    bad.write_text('classes = ["bg", "hole"]\n[map]\nbg = ["background"]\nhole = ["sinkhole"]\n')
    with pytest.raises(RoadtwinError) as err:
        run_render(road, tmp_path / "out", RenderOptions(frames=1, size="16x12", classmap=str(bad),
                                                         executor="serial"), pm=pm)
    msg = str(err.value)
    assert "'sinkhole'" in msg and str(bad) in msg and "\n" not in msg


def test_bad_rig_through_the_real_command_is_exit_2_and_one_line(road, tmp_path):
    res = subprocess.run([sys.executable, "-m", "roadtwin_core.cli", "render", str(road), "-o", str(tmp_path / "o"),
                          "--rig", "drone"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and "drone" in lines[0], res.stderr


def _has_cuda() -> bool:
    from roadtwin_core.warp_runtime import start_warp

    return start_warp().get_cuda_device_count() > 0


def test_asking_for_a_missing_gpu_is_one_line(road, tmp_path):
    """`--device cuda` where there is none: exit 2 and one line naming the device, not warp's
    native CUDA error lines before it."""
    if _has_cuda():
        pytest.skip("this machine has a CUDA device")
    res = subprocess.run([sys.executable, "-m", "roadtwin_core.cli", "render", str(road), "-o", str(tmp_path / "o"),
                          "--frames", "1", "--size", "80x50", "--backend", "warp", "--device", "cuda"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and "no device 'cuda'" in lines[0], res.stderr
    assert not (tmp_path / "o").exists()


def test_rendering_on_a_machine_without_cuda_prints_no_driver_notice(road, tmp_path):
    """warp's native library announces a missing NVIDIA driver on stderr at start-up; the CPU is
    the intended device there, so a user must not see it (nor a wrapper parse it as an error)."""
    res = subprocess.run([sys.executable, "-m", "roadtwin_core.cli", "render", str(road), "-o", str(tmp_path / "o"),
                          "--frames", "1", "--size", "80x50", "--backend", "warp"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "CUDA" not in res.stderr, res.stderr
    assert (tmp_path / "o" / "meta.json").is_file()


def test_crack_growth_keeps_pothole_over_crack_over_lane():
    from roadtwin_core.render.classmap import load_class_map, parse_class_map

    m = load_class_map("road_defects_br")
    assert dict(m.dilate_px) == {"crack": 1}
    lab = np.array([[0, 1, 1, 1, 255],
                    [0, 2, 2, 3, 255],
                    [1, 1, 1, 3, 1]], np.uint8)
    # the crack grows by one pixel (4-neighbours: cv2's 3x3 ellipse) over background and lane,
    # never over the pothole or ignore
    expected = np.array([[0, 2, 2, 1, 255],
                         [2, 2, 2, 3, 255],
                         [1, 2, 2, 3, 1]], np.uint8)
    np.testing.assert_array_equal(m.spread(lab), expected)
    with pytest.raises(RoadtwinError, match=r"\[dilate_px\] crack"):
        parse_class_map('classes = ["a", "crack"]\n[map]\ncrack = ["crack"]\n[dilate_px]\ncrack = -1\n', "f.toml")


class YoloBoxes:
    """A third party's dataset format: one YOLO text file per frame, ``class cx cy w h`` (image
    fractions) per defect instance in view, written through the ``dataset_formats`` hook."""

    name, description, needs_stereo = "yolo_boxes", "YOLO boxes of defect instances", False

    def writer(self, dataset):
        fmt = self

        class Writer:
            def __init__(self):
                (dataset.root / "yolo").mkdir()
                self.frames = 0

            def add(self, k, stem, frame, files):
                h, w = frame.instance.shape
                lines = []
                for inst in dataset.instances:
                    ys, xs = np.nonzero(frame.instance == inst["id"])
                    if len(xs):
                        cls = dataset.categories.index(inst["type"])
                        x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
                        lines.append(f"{cls} {(x0 + x1) / 2 / w:.6f} {(y0 + y1) / 2 / h:.6f} "
                                     f"{(x1 - x0) / w:.6f} {(y1 - y0) / h:.6f}")
                (dataset.root / "yolo" / f"{stem}.txt").write_text("".join(line + "\n" for line in lines))
                files[fmt.name] = f"yolo/{stem}.txt"
                self.frames += 1
                return {"yolo_boxes": len(lines)}

            def finish(self):
                (dataset.root / "yolo" / "classes.txt").write_text("\n".join(dataset.categories) + "\n")

        return Writer()


def test_a_plugin_adds_a_dataset_format(road, tmp_path):
    """`--formats` reaches a plugin's format: its writer gets every frame, its files are listed in
    meta.json, its boxes enclose the instance pixels the core's COCO writer saved; a plugin format
    named like a core one does not replace the core's."""
    class FakeMmseg(YoloBoxes):
        name = "mmseg"

    mod = types.ModuleType("fake_yolo")
    mod.roadtwin_register_dataset_formats = roadtwin_core.hookimpl(lambda register: [register(YoloBoxes()),
                                                                                      register(FakeMmseg())])
    pm = PluginManager(load_entry_points=False)
    for plugin, name in ((roadtwin_defects, "defects"), (roadtwin_warp_render, "warp_render"), (mod, "yolo")):
        pm.register(plugin, name=name)
    out = tmp_path / "out"
    run_render(road, out, RenderOptions(frames=4, size="160x100", views="defects:1.0",
                                        formats="coco,yolo_boxes,mmseg", executor="serial", seed=3), pm=pm)
    meta = json.loads((out / "meta.json").read_text())
    assert {i["type"] for i in meta["instances"]} <= set((out / "yolo/classes.txt").read_text().split())  # finish() ran
    boxes = 0
    for f in meta["frames"]:
        inst = cv2.imread(str(out / f["files"]["instance"]), cv2.IMREAD_UNCHANGED)
        lines = (out / f["files"]["yolo_boxes"]).read_text().splitlines()
        assert f["yolo_boxes"] == len(lines) == len([i for i in np.unique(inst) if i > 0])
        for line in lines:
            _, cx, cy, w, h = map(float, line.split())
            x0, x1 = (cx - w / 2) * 160, (cx + w / 2) * 160
            y0, y1 = (cy - h / 2) * 100, (cy + h / 2) * 100
            inside = np.zeros(inst.shape, bool)
            inside[int(round(y0)):int(round(y1)), int(round(x0)):int(round(x1))] = True
            ids = set(np.unique(inst[inside])) - {0}
            assert ids, line                                 # the box holds an instance ...
            assert any((inst[~inside] == i).sum() == 0 for i in ids), line  # ... all of its pixels
            boxes += 1
        # the core's mmseg writer, not the plugin's same-named format
        assert f["files"]["semantic"].startswith("mmseg/ann_dir/")
    assert boxes >= 2                                        # every frame aims at a defect
    with pytest.raises(RoadtwinError, match="unknown format 'yolo' .*yolo_boxes"):
        run_render(road, tmp_path / "o2", RenderOptions(frames=1, size="80x50", formats="yolo",
                                                        executor="serial"), pm=pm)


def test_frames_finished_on_threads_write_what_one_thread_writes(road, pm, tmp_path):
    """The in-process path (a GPU device, or --executor serial) finishes and writes frames on
    ``workers`` threads; the files and meta.json records must not depend on their number."""
    outs, summaries = {}, {}
    for threads in (1, 3):
        outs[threads] = tmp_path / f"t{threads}"
        summaries[threads] = run_render(road, outs[threads], RenderOptions(
            frames=6, rig="survey", size="64x40", views="defects:0.5", randomize=True,
            classmap="builtin:road_defects_br", formats="mmseg,coco,depth", executor="serial", workers=threads,
            seed=4), pm=pm)
    assert_same_dataset(outs[1], outs[3])
    coco = json.loads((outs[3] / "coco/annotations/instances_train.json").read_text())
    assert [a["id"] for a in coco["annotations"]] == list(range(1, len(coco["annotations"]) + 1))
    assert [a["image_id"] for a in coco["annotations"]] == sorted(a["image_id"] for a in coco["annotations"])
    phases = summaries[3]["phase_timings_s"]
    assert {"stage_read", "view_sampling", "randomize", "prepare", "render", "sensor", "labels", "write"} <= set(phases)
    assert all(v >= 0 for v in phases.values())


def serial_then_forked(road, pm, tmp_path, monkeypatch, frames: int, formats: str) -> dict:
    """The same survey render through the serial executor (threads) and through the GPU path
    (forked finishing processes, forced on the CPU): {"serial": folder, "local": folder}."""
    import roadtwin_core.apps.render.run as run_mod

    outs = {}
    for name in ("serial", "local"):
        if name == "local":
            monkeypatch.setattr(run_mod, "_on_gpu", lambda device: True)
        outs[name] = tmp_path / name
        run_render(road, outs[name], RenderOptions(frames=frames, rig="survey", size="64x40", views="defects:0.5",
                                                   randomize=True, classmap="builtin:road_defects_br",
                                                   formats=formats, executor=name, workers=2, seed=6), pm=pm)
    return outs


def test_frames_finished_in_forked_processes_write_what_the_serial_path_writes(road, pm, tmp_path, monkeypatch):
    """On a GPU device frames render in the main process and forked processes finish and write
    them; forced here on the CPU (the same code path but the device), it must write the serial bytes."""
    outs = serial_then_forked(road, pm, tmp_path, monkeypatch, 5, "mmseg,coco")
    assert_same_dataset(outs["serial"], outs["local"])


def test_device_finished_frames_through_the_shared_ring_write_what_threads_write(road, pm, tmp_path, monkeypatch):
    """Frames finished on the device reach forked finishing processes through shared memory
    (``frame_sink.FrameRing``), not pickled: the files must be the threads' (no ring), and the
    ring must have carried every frame."""
    import roadtwin_core.apps.render.frame_sink as sink_mod

    monkeypatch.setattr(sink_mod, "finish_on_device", lambda ctx, jobs, device: True)
    carried = []
    put = sink_mod.FrameRing.put
    monkeypatch.setattr(sink_mod.FrameRing, "put", lambda self, k, arrays: carried.append(k) or put(self, k, arrays))
    outs = serial_then_forked(road, pm, tmp_path, monkeypatch, 7, "mmseg,coco,depth")
    assert carried == list(range(7))
    assert_same_dataset(outs["serial"], outs["local"])


def test_frame_ring_slots_hold_their_frames_until_reused():
    """Each of a ring's slots keeps its frame's arrays (shape, dtype, values) while the next
    ``slots - 1`` frames are put; arrays too large for a slot are refused (they go pickled)."""
    from roadtwin_core.apps.render.frame_sink import FrameRing

    ring = FrameRing(slot_bytes=64 * 40 * 12 + 4096, slots=4)
    rng = np.random.default_rng(0)
    frames = [{"rgb8": rng.integers(0, 255, (40, 64, 3), dtype=np.uint8),
               "depth": rng.random((40, 64), dtype=np.float32),
               "instance": rng.integers(0, 99, (40, 64), dtype=np.int32)} for _ in range(4)]
    layouts = [ring.put(k, f) for k, f in enumerate(frames)]
    for f, layout in zip(frames, layouts):
        got = ring.get(layout)
        for key, a in f.items():
            assert got[key].dtype == a.dtype and got[key].shape == a.shape
            np.testing.assert_array_equal(got[key], a)
    assert ring.put(4, {"big": np.zeros(64 * 40 * 16, np.uint8)}) is None


def test_frames_planned_in_forked_blocks_write_what_planning_here_writes(road, pm, tmp_path, monkeypatch):
    """Frame i's camera, look and camera model depend on (seed, i) alone, so planning frames in
    blocks of 2 on a pool of forked processes must write the dataset planned in one block here."""
    import roadtwin_core.apps.render.planning as planning

    def render(name):
        run_render(road, tmp_path / name, RenderOptions(frames=7, rig="survey", size="64x40", views="defects:0.5:clear",
                                                        randomize=True, classmap="builtin:road_defects_br",
                                                        formats="mmseg", executor="serial", seed=4), pm=pm)
        return tmp_path / name

    here = render("here")
    monkeypatch.setattr(planning, "PARALLEL_FROM", 1)
    monkeypatch.setattr(planning, "BLOCK", 2)
    monkeypatch.setattr(planning, "_usable_cores", lambda: 3)
    pools = []
    get_context = planning.multiprocessing.get_context
    monkeypatch.setattr(planning.multiprocessing, "get_context", lambda method: pools.append(method) or get_context(method))
    forked = render("forked")
    assert pools == ["fork"]                                    # the blocks went to a forked pool
    assert_same_dataset(here, forked)
    frames = json.loads((forked / "meta.json").read_text())["frames"]
    assert [f["index"] for f in frames] == list(range(7))
    assert len({json.dumps(f["randomization"]) for f in frames}) == 7      # every frame drew its own look


def test_on_a_gpu_the_finishing_processes_plan_the_frames_while_the_scene_uploads(road, pm, tmp_path, monkeypatch):
    """On a GPU device (forced here on the CPU) the frames' blocks are planned by the finishing
    processes, forked before the device is touched, while this process uploads the scene; the
    dataset must be the one planned here, in one process."""
    import os
    import time

    import roadtwin_core.apps.render.planning as planning
    import roadtwin_core.apps.render.run as run_mod

    def render(name, executor):
        run_render(road, tmp_path / name, RenderOptions(frames=7, rig="survey", size="64x40", views="defects:0.5:clear",
                                                        randomize=True, classmap="builtin:road_defects_br",
                                                        formats="mmseg", executor=executor, workers=2, seed=4), pm=pm)
        return tmp_path / name

    here = render("here", "serial")
    monkeypatch.setattr(planning, "PARALLEL_FROM", 1)
    monkeypatch.setattr(planning, "BLOCK", 2)
    monkeypatch.setattr(run_mod, "_on_gpu", lambda device: True)
    pools = []
    get_context = planning.multiprocessing.get_context
    monkeypatch.setattr(planning.multiprocessing, "get_context", lambda method: pools.append(method) or get_context(method))
    block, prepared_scene, log = planning.FramePlanner.block, run_mod.prepared_scene, tmp_path / "log"
    log.mkdir()

    def slow_block(self, start, stop):
        time.sleep(0.3)
        (log / f"block{start}").write_text(f"{os.getpid()} {time.time()}")
        return block(self, start, stop)

    def timed_upload(ctx):
        (log / "upload").write_text(f"{os.getpid()} {time.time()}")
        return prepared_scene(ctx)

    monkeypatch.setattr(planning.FramePlanner, "block", slow_block)
    monkeypatch.setattr(run_mod, "prepared_scene", timed_upload)
    gpu = render("gpu", "local")
    assert_same_dataset(here, gpu)
    assert pools == ["fork"]                                     # one forked pool, the sink's: none for planning
    blocks = [(int(p), float(t)) for p, t in (f.read_text().split() for f in log.glob("block*"))]
    upload_pid, upload_at = log.joinpath("upload").read_text().split()
    assert len(blocks) == 4 and all(pid != os.getpid() for pid, _ in blocks)
    assert int(upload_pid) == os.getpid() and float(upload_at) < max(t for _, t in blocks)   # uploaded meanwhile

def test_meta_json_puts_a_frame_a_line_and_reads_back_equal():
    from roadtwin_core.apps.render.writers.dataset import meta_json

    meta = {"format": "x", "frames": [{"index": i, "cam_to_world": [[1.5, 0.0]], "files": {"rgb": f"{i}.jpg"}}
                                      for i in range(3)], "events": None}
    text = meta_json(meta)
    assert json.loads(text) == meta
    assert [json.loads(line.strip().rstrip(",")) for line in text.splitlines() if '"index"' in line] == meta["frames"]
    assert json.loads(meta_json({**meta, "frames": []})) == {**meta, "frames": []}


class _Unplannable:
    """Camera source whose every block fails; the first block fails last."""

    frames = 40

    def block(self, start, stop):
        import time

        from roadtwin_core.errors import RoadtwinError

        if start == 0:
            time.sleep(0.5)
        raise RoadtwinError(f"view {start}: could not aim a view at a defect in 60 tries")


def test_a_frame_that_cannot_be_planned_is_named_as_when_planned_here(monkeypatch):
    """On the forked pool the error is the first bad frame's, as in one process, whichever block
    fails first."""
    import roadtwin_core.apps.render.planning as planning
    from roadtwin_core.errors import RoadtwinError

    monkeypatch.setattr(planning, "BLOCK", 10)
    planner = planning.FramePlanner(_Unplannable(), None, 0)
    for processes in (1, 4):
        with pytest.raises(RoadtwinError, match=r"^view 0: "):
            planning.plan_all(planner, 40, processes=processes, parallel_from=1)
