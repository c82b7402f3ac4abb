"""The renderer, cameras, event simulator, dataset writers and ``roadtwin render``, checked
against geometry built here (planes, flat-bottomed pits, a block) and closed forms, and the
written datasets read back with the ordinary readers (cv2, pycocotools, h5py, json, torch).

Images are tiny (at most 160x120) and frames few; one real town is composed per module.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import triangle
import typer
from typer.testing import CliRunner

import roadtwin_core.plugins as plugins_mod
import roadtwin_defects
import roadtwin_warp_render
from roadtwin_core import PluginManager, RoadtwinError
from roadtwin_core.apps.render import RenderOptions, parse_size, run_render
from roadtwin_core.apps.render.writers import rle_decode, rle_encode
from roadtwin_core.cli.render import render
from roadtwin_core.render import (Camera, EventSimulator, Intrinsics, RenderParams, StereoCamera, build_render_mesh,
                                  look_from)
from roadtwin_core.usd.town_reader import TownDefect, TownMesh, TownScene

ROOT = Path(__file__).resolve().parents[2]
HAS_OPEN3D = roadtwin_warp_render.renderer._has_open3d()
BACKENDS = ["warp"] + (["open3d"] if HAS_OPEN3D else [])


# --------------------------------------------------------------------------- fixtures, geometry
@pytest.fixture(scope="module")
def pm():
    m = PluginManager(load_entry_points=False)
    m.register(roadtwin_defects, name="defects")
    m.register(roadtwin_warp_render, name="warp_render")
    return m


@pytest.fixture(scope="module")
def renderer(pm):
    return pm.get("renderers", "warp")


def pit(rim: np.ndarray, depth: float, floor_scale: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """A flat-bottomed pit under a convex CCW rim polygon at z = 0: sloped walls down to a floor
    (the rim shrunk towards its centroid) at z = -depth."""
    k = len(rim)
    c = rim.mean(axis=0)
    floor = c + floor_scale * (rim - c)
    v = np.vstack([np.column_stack([rim, np.zeros(k)]), np.column_stack([floor, np.full(k, -depth)])])
    f = []
    for i in range(k):
        j = (i + 1) % k
        f += [(i, j, k + j), (i, k + j, k + i)]
    f += [(k, k + i, k + i + 1) for i in range(1, k - 1)]
    return v, np.array(f)


def road_with_holes(half: float, holes: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A square road plane at z = 0 with polygonal holes (constrained triangulation)."""
    outer = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    verts, segs, n = [outer], [[(i, (i + 1) % 4) for i in range(4)]], 4
    for h in holes:
        verts.append(h)
        segs.append([(n + i, n + (i + 1) % len(h)) for i in range(len(h))])
        n += len(h)
    data = {"vertices": np.vstack(verts), "segments": np.vstack(segs)}
    if holes:
        data["holes"] = np.array([h.mean(axis=0) for h in holes])
    t = triangle.triangulate(data, "p")
    return np.column_stack([t["vertices"], np.zeros(len(t["vertices"]))]), t["triangles"]


def polygon(center, radius, n, phase=0.0) -> np.ndarray:
    a = phase + 2 * np.pi * np.arange(n) / n
    return np.column_stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)])


def scene(roads=(), defects=()) -> TownScene:
    """A TownScene by hand: roads [(kind, v, f)], defects [(type, v, f)]."""
    s = TownScene("Test", "test")
    s.roads = [TownMesh(f"/Test/Roads/seg{i}", kind, np.asarray(v, float), np.asarray(f)) for i, (kind, v, f) in enumerate(roads)]
    s.defects = [TownDefect(f"D{i:05d}", t, {"type": t}, [TownMesh(f"/Test/Defects/D{i:05d}/seg0", t, np.asarray(v, float), np.asarray(f))])
                 for i, (t, v, f) in enumerate(defects)]
    return s


def plane(normal=(0.0, 0.0, 1.0), half=200.0):
    n = np.asarray(normal, float)
    n /= np.linalg.norm(n)
    a = np.cross(n, [1.0, 0, 0]) if abs(n[0]) < 0.9 else np.cross(n, [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    v = np.array([-a - b, a - b, a + b, -a + b]) * half
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def one(renderer, town, cam, **kw):
    params = RenderParams(**{"shadows": False, **kw})
    return next(iter(renderer.render(town, [cam], params)))


# --------------------------------------------------------------------------- geometry vs closed forms
@pytest.mark.parametrize("backend", BACKENDS)
def test_plane_depth_matches_closed_form(renderer, backend):
    h, pitch = 1.7, math.radians(-20.0)
    intr = Intrinsics.from_fov(64, 48, 90.0)
    cam = Camera(intr, look_from((3.0, -2.0, h), math.radians(30.0), pitch))
    fr = one(renderer, scene([("driving", *plane())]), cam, backend=backend, shade=False)
    v = np.arange(intr.height)[:, None].repeat(intr.width, 1)
    yn = (v - intr.cy) / intr.fy
    den = math.sin(-pitch) + yn * math.cos(pitch)       # z-depth Z = h / den for the plane z = 0
    expected = np.where(den > 0.02, h / np.where(den > 0.02, den, 1), 0)
    valid = (den > 0.02) & (expected < 150)
    assert valid.sum() > 0.4 * v.size
    np.testing.assert_allclose(fr.depth[valid], expected[valid], rtol=2e-5)
    assert (fr.depth[den < -0.02] == 0).all()                 # sky: no hit
    assert (fr.semantic[den < -0.02] == 0).all()              # background class


@pytest.mark.parametrize("backend", BACKENDS)
def test_pothole_floor_depth_and_labels(renderer, backend):
    rim = polygon((0.0, 0.0), 0.5 * math.sqrt(2), 4, math.pi / 4)    # 1 m square
    d = 0.12
    town = scene([("driving", *road_with_holes(20.0, [rim]))], [("pothole", *pit(rim, d))])
    intr = Intrinsics.from_fov(64, 64, 60.0)
    cam = Camera(intr, look_from((0.0, 0.0, 2.0), 0.0, -math.pi / 2))
    fr = one(renderer, town, cam, backend=backend, shade=False)
    c = slice(27, 37)
    np.testing.assert_allclose(fr.depth[c, c], 2.0 + d, atol=2e-5)          # the floor, straight down
    np.testing.assert_allclose(fr.depth[:4, :4], 2.0, atol=2e-5)            # the road around it
    classes = build_render_mesh(town).classes
    assert (fr.semantic[c, c] == classes.index("pothole")).all()
    assert (fr.instance[c, c] == 1).all() and (fr.instance[:4, :4] == 0).all()
    assert (fr.semantic[:4, :4] == classes.index("driving")).all()
    np.testing.assert_allclose(fr.normal[c, c].reshape(-1, 3), np.tile([0.0, 0.0, -1.0], (100, 1)), atol=1e-5)


def test_tilted_plane_normals(renderer, tmp_path):
    n = np.array([0.0, math.sin(math.radians(25)), math.cos(math.radians(25))])
    cam = Camera(Intrinsics.from_fov(48, 32, 80.0), look_from((0.0, 0.0, 3.0), 0.3, math.radians(-30)))
    fr = one(renderer, scene([("driving", *plane(n))]), cam, shade=False)
    hit = fr.depth > 0
    assert hit.mean() > 0.5
    expected = cam.rotation.T @ n
    expected = expected if expected[2] < 0 else -expected     # faces the camera (z forward)
    err = np.degrees(np.arccos(np.clip(fr.normal[hit] @ expected, -1, 1)))
    assert err.max() < 0.05
    assert (fr.normal[~hit] == 0).all()


def test_backends_agree(renderer):
    if not HAS_OPEN3D:
        pytest.skip("open3d not installed")
    rim = polygon((1.0, 0.3), 0.6, 6)
    town = build_render_mesh(scene([("driving", *road_with_holes(30.0, [rim]))], [("pothole", *pit(rim, 0.1))]))
    cam = Camera(Intrinsics.from_fov(64, 48, 70.0), look_from((-2.0, 0.2, 1.5), 0.0, math.radians(-25)))
    a = one(renderer, town, cam, backend="warp")
    b = one(renderer, town, cam, backend="open3d")
    same = a.face == b.face
    assert same.mean() > 0.995
    np.testing.assert_allclose(a.depth[same], b.depth[same], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(a.rgb[same], b.rgb[same], atol=1e-4)


def test_stereo_consistency_and_occlusion(renderer):
    rim = polygon((2.0, 0.6), 0.55, 8)
    block_v = np.array([[x, y, z] for z in (0.0, 0.5) for x, y in ((3.0, -1.0), (3.6, -1.0), (3.6, -0.2), (3.0, -0.2))])
    block_f = np.array([[4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
                        [3, 0, 4], [3, 4, 7]])
    town = scene([("driving", *road_with_holes(40.0, [rim])), ("driving", block_v, block_f)],
                 [("pothole", *pit(rim, 0.15))])
    base = 0.3
    intr = Intrinsics.from_fov(128, 96, 80.0)
    rig = StereoCamera(Camera(intr, look_from((-1.0, -0.4, 1.4), 0.05, math.radians(-25))), base)
    fr = one(renderer, town, rig)
    hit = fr.depth > 0
    np.testing.assert_allclose(fr.disparity[hit], intr.fx * base / fr.depth[hit], rtol=1e-5)
    assert (fr.disparity[~hit] == 0).all()
    # warp the right image onto the left with the left disparity
    left, right = fr.rgb.astype(np.float32), fr.rgb_right.astype(np.float32)
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float32), np.arange(intr.height, dtype=np.float32))
    warped = cv2.remap(right, u - fr.disparity.astype(np.float32), v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=(-1, -1, -1))
    ok = hit & ~fr.occluded & (warped[..., 0] >= 0)
    err = np.abs(warped - left).mean(axis=-1)
    assert ok.mean() > 0.4
    assert fr.occluded[hit].mean() > 0.005         # the block hides some road from the right camera
    assert err[ok].mean() < 0.004 and np.percentile(err[ok], 95) < 0.01     # linear radiance, sky ~1
    # where the left pixel is occluded the right camera sees something else
    occ = hit & fr.occluded & (warped[..., 0] >= 0)
    assert err[occ].mean() > 3 * err[ok].mean()


def test_instance_masks_match_projected_footprints(renderer):
    from matplotlib.path import Path as PolyPath

    rims = [polygon((0.0, 0.5), 0.6, 6), polygon((0.6, -0.9), 0.55, 4, 0.3)]
    town = scene([("driving", *road_with_holes(30.0, rims))], [("pothole", *pit(rims[0], 0.1)), ("crack", *pit(rims[1], 0.03))])
    intr = Intrinsics.from_fov(256, 192, 70.0)
    cam = Camera(intr, look_from((-3.0, -0.2, 1.6), 0.0, math.radians(-30)))
    fr = one(renderer, town, cam, shade=False)
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    for k, rim in enumerate(rims, start=1):
        uv, z = cam.project(np.column_stack([rim, np.zeros(len(rim))]))
        assert (z > 0).all()
        poly = np.zeros((intr.height, intr.width), np.uint8)
        cv2.fillPoly(poly, [np.rint(uv * 256).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=8)
        mask = fr.instance == k
        iou = (mask & (poly > 0)).sum() / (mask | (poly > 0)).sum()
        assert mask.sum() > 400 and iou > 0.9, (k, iou, mask.sum())
        # fillPoly also paints the outline; the pixel-centre test is the renderer's exact rule
        centre = PolyPath(uv).contains_points(np.column_stack([u.ravel(), v.ravel()])).reshape(mask.shape)
        assert (mask & centre).sum() / (mask | centre).sum() > 0.99


# --------------------------------------------------------------------------- events
def test_event_simulator_counts_and_timestamps():
    sim = EventSimulator(3, 2, threshold=0.2, sigma=0.0, refractory_s=0.0, eps=1e-9)
    img = np.full((2, 3), 0.1)
    sim.reset(img, 0.0)
    ev = sim.step(img * math.exp(0.7), 0.01)          # log ramp of 0.7 over 10 ms: 3 ON events per pixel
    assert len(ev["t"]) == 18 and (ev["p"] == 1).all()
    np.testing.assert_allclose(np.unique(ev["t"]), [0.01 * 0.2 / 0.7, 0.01 * 0.4 / 0.7, 0.01 * 0.6 / 0.7], rtol=1e-6)
    assert np.all(np.diff(ev["t"]) >= 0)
    ev = sim.step(img, 0.02)                          # back down by 0.7 from ref 0.6: 3 OFF events
    assert len(ev["t"]) == 18 and (ev["p"] == -1).all()
    # refractory period: events 2 ms apart with a 3 ms refractory -> every other one
    sim = EventSimulator(1, 1, threshold=0.2, sigma=0.0, refractory_s=0.003, eps=1e-9)
    sim.reset(np.full((1, 1), 1.0), 0.0)
    ev = sim.step(np.full((1, 1), math.exp(1.0 + 1e-6)), 0.01)
    np.testing.assert_allclose(ev["t"], [0.002, 0.006, 0.010], rtol=1e-5)


@pytest.mark.parametrize("direction", [+1, -1])
def test_event_polarity_on_rendered_scene(renderer, direction):
    cam = Camera(Intrinsics.from_fov(32, 24, 60.0), look_from((0.0, 0.0, 2.0), 0.0, math.radians(-60)))
    town = build_render_mesh(scene([("driving", *plane())]))
    elevations = [15.0, 25.0, 35.0, 45.0, 55.0][::direction]
    sim = EventSimulator(32, 24, seed=1)
    events = []
    for k, el in enumerate(elevations):
        fr = one(renderer, town, cam, sun_elevation_deg=el, sun_azimuth_deg=180.0)
        events.append(sim.step(fr.rgb, k * 0.002))
    p = np.concatenate([e["p"] for e in events])
    assert len(p) > 32 * 24
    assert (p == direction).all()


# --------------------------------------------------------------------------- RLE
def _coco_rle_to_mask(rle: dict) -> np.ndarray:
    """COCO compressed RLE decoded from the format's definition (pycocotools' ``rleFrString``),
    independently of roadtwin's decoder: characters offset by 48 carry 5 data bits, 0x20 = more
    characters follow, 0x10 in the last one = negative; from the third count on, each is stored
    as its difference to the count two before; runs alternate 0/1 in column-major order."""
    s, counts, p = rle["counts"], [], 0
    while p < len(s):
        x, k, more = 0, 0, True
        while more:
            c = ord(s[p]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p, k = p + 1, k + 1
            if not more and c & 0x10:
                x |= -1 << (5 * k)
        counts.append(x + counts[-2] if len(counts) > 2 else x)
    h, w = rle["size"]
    return np.repeat(np.arange(len(counts)) % 2, counts).astype(bool).reshape(w, h).T


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # pycocotools vs numpy 2
def test_rle_roundtrip_and_pycocotools():
    rng = np.random.default_rng(0)
    masks = [np.zeros((5, 7), bool), np.ones((4, 3), bool), np.eye(6, dtype=bool)]
    m = np.zeros((9, 11), bool)
    m[0, 0] = True
    masks.append(m)
    masks += [rng.random((40, 50)) < p for p in (0.05, 0.5, 0.95)]
    blob = np.zeros((300, 400), np.uint8)
    cv2.circle(blob, (200, 150), 90, 1, -1)
    masks.append(blob.astype(bool))
    for mask in masks:
        rle = rle_encode(mask)
        np.testing.assert_array_equal(rle_decode(rle), mask)
    # hand-checked: a 2x2 mask [[0,1],[1,1]] in column-major order is 0,1,1,1 -> runs [1, 3]
    assert rle_decode({"size": [2, 2], "counts": [1, 3]}).tolist() == [[0, 1], [1, 1]]
    assert rle_decode(rle_encode(np.array([[0, 1], [1, 1]], bool))).tolist() == [[0, 1], [1, 1]]
    # hand-encoded strings: runs [1, 3] -> "1", "3"; a 10x10 of ones: runs [0, 100], and 100 =
    # 3 * 32 + 4 takes two characters: 4 | 0x20 (more) -> chr(48 + 36) = "T", then 3 -> "3"
    assert rle_encode(np.array([[0, 1], [1, 1]], bool))["counts"] == "13"
    assert rle_encode(np.ones((10, 10), bool))["counts"] == "0T3"
    assert _coco_rle_to_mask({"size": [10, 10], "counts": "0T3"}).all()
    for mask in masks:                        # the format's definition, not roadtwin's own decoder
        np.testing.assert_array_equal(_coco_rle_to_mask(rle_encode(mask)), mask)
    mask_api = pytest.importorskip("pycocotools.mask")
    for mask in masks:
        ref = mask_api.encode(np.asfortranarray(mask.astype(np.uint8)))
        assert rle_encode(mask)["counts"] == ref["counts"].decode()
        np.testing.assert_array_equal(mask_api.decode({"size": list(mask.shape), "counts": rle_encode(mask)["counts"]}), mask)


# --------------------------------------------------------------------------- the command on a real town
@pytest.fixture(scope="module")
def town_stage(tmp_path_factory):
    from roadtwin_core.apps.compose.run import compose

    out = tmp_path_factory.mktemp("town") / "town"
    town = compose(ROOT / "stages/town.usda", out, defects=3, surface="flat", preview=False).town
    retexture(town)
    return town


def retexture(town: Path) -> None:
    """What a user re-texturing the town in another tool writes: a strongest sublayer binding a
    noise texture (world-planar st, 4 m a repeat) to every road and defect mesh. Makes the
    sample town's appearance independent of the composer's own looks (events need texture)."""
    from PIL import Image
    from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

    rng = np.random.default_rng(0)
    (town.parent / "textures").mkdir(exist_ok=True)
    noise = cv2.resize(rng.integers(40, 160, size=(16, 16, 3), dtype=np.uint8), (64, 64), interpolation=cv2.INTER_CUBIC)
    Image.fromarray(noise).save(town.parent / "textures/test_noise.png")
    src = Usd.Stage.Open(str(town))
    root = src.GetDefaultPrim().GetPath()
    layer_path = town.parent / "layers/test_looks.usda"
    stage = Usd.Stage.CreateNew(str(layer_path))
    mat = UsdShade.Material.Define(stage, root.AppendPath("TestLooks/Noise"))
    surf = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("Surface"))
    surf.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    tex = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("Tex"))
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("../textures/test_noise.png")
    reader = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("St"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    for prim in src.Traverse():
        if prim.IsA(UsdGeom.Mesh) and "/Collision/" not in str(prim.GetPath()):
            pts = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(), np.float32)
            over = stage.OverridePrim(prim.GetPath())
            UsdGeom.PrimvarsAPI(over).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                    UsdGeom.Tokens.vertex).Set(Vt.Vec2fArray.FromNumpy(pts[:, :2] / 4))
            UsdShade.MaterialBindingAPI.Apply(over).Bind(mat)
    stage.GetRootLayer().Save()
    root_layer = Sdf.Layer.FindOrOpen(str(town))
    root_layer.subLayerPaths.insert(0, "./layers/test_looks.usda")
    root_layer.Save()


def defect_poses(stage: Path) -> list[dict]:
    """One camera 3 m before each defect, 1.6 m above it, looking at it."""
    from roadtwin_core.usd import load_town

    poses = []
    for d in load_town(stage).defects:
        x, y, _ = d.attributes["poseXYYaw"]
        z = max(p.vertices[:, 2].max() for p in d.pieces)
        poses.append({"position": [x - 3.0, y, z + 1.6], "yaw_deg": 0.0, "pitch_deg": -28.0})
    return poses


def invoke(pm, args: list[str]):
    """``render`` through typer's CliRunner on a small app (what ``roadtwin render`` runs)."""
    app = typer.Typer()
    app.callback()(lambda: None)
    app.command()(render)
    old = plugins_mod._manager
    plugins_mod._manager = pm
    try:
        return CliRunner().invoke(app, ["render", *map(str, args)])
    finally:
        plugins_mod._manager = old


@pytest.fixture(scope="module")
def rendered(town_stage, pm, tmp_path_factory):
    """Stereo, events and every format, one camera facing each defect."""
    base = tmp_path_factory.mktemp("render")
    poses = base / "poses.json"
    poses.write_text(json.dumps({"poses": defect_poses(town_stage)}))
    res = invoke(pm, [town_stage, "-o", base / "out", "--frames", "3", "--size", "96x64", "--stereo", "--events",
                      "--event-frames", "20", "--speed", "15", "--event-size", "128x96", "--poses", poses,
                      "--hfov", "70", "--formats", "kitti,mmseg,coco,depth,normal"])
    assert res.exit_code == 0, (res.output, res.exception)
    assert "rendered" in res.output
    return base / "out"


def test_written_dataset_loads_with_ordinary_readers(rendered):
    out = rendered
    meta = json.loads((out / "meta.json").read_text())
    k = meta["intrinsics"]
    base = meta["stereo"]["baseline_m"]
    assert len(meta["frames"]) == 3 and (k["width"], k["height"]) == (96, 64)
    names = {c["id"]: c["name"] for c in meta["classes"]}
    for fr in meta["frames"]:
        f = fr["files"]
        depth = np.load(out / f["depth"])
        assert depth.dtype == np.float32 and depth.shape == (64, 96)
        # KITTI disparity: uint16 PNG / 256 == f*B/Z within 1/256 where valid, 0 elsewhere
        disp = cv2.imread(str(out / f["disparity"]), cv2.IMREAD_UNCHANGED)
        assert disp.dtype == np.uint16
        valid = depth > 0
        expected = np.where(valid, k["fx"] * base / np.where(valid, depth, 1), 0)
        assert (disp[~valid] == 0).all() and (disp[valid] > 0).all()
        assert np.abs(disp[valid] / 256.0 - expected[valid]).max() <= 1 / 512 + 1e-6
        noc = cv2.imread(str(out / f["disparity_noc"]), cv2.IMREAD_UNCHANGED)
        assert ((noc == disp) | (noc == 0)).all()
        for img in ("kitti_left", "kitti_right", "rgb"):
            assert cv2.imread(str(out / f[img])).shape == (64, 96, 3)
        ann = cv2.imread(str(out / f["semantic"]), cv2.IMREAD_UNCHANGED)
        assert ann.dtype == np.uint8 and set(np.unique(ann)) <= set(names) | {255}
        assert cv2.imread(str(out / f["semantic"].replace("ann_dir", "img_dir"))).shape == (64, 96, 3)
        normal = np.load(out / f["normal"])
        np.testing.assert_allclose(np.linalg.norm(normal[valid], axis=-1), 1.0, atol=1e-5)
        assert cv2.imread(str(out / f["depth"].replace(".npy", ".png"))).shape == (64, 96, 3)
    assert (out / "kitti/training/calib_cam_to_cam/000000.txt").read_text().startswith("S_rect_02")
    assert (out / "preview.png").exists()
    assert not list(out.parent.glob(".out.tmp-*"))


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # pycocotools vs numpy 2
def test_coco_masks_decode_to_instance_maps(rendered):
    out = rendered
    coco = json.loads((out / "coco/annotations/instances_train.json").read_text())
    meta = json.loads((out / "meta.json").read_text())
    cats = {c["id"]: c["name"] for c in coco["categories"]}
    assert len(coco["images"]) == 3 and len(coco["annotations"]) >= 2     # each camera faces a defect
    try:
        from pycocotools import mask as mask_api

        decode = mask_api.decode
    except ImportError:
        decode = _coco_rle_to_mask              # the format's definition, not roadtwin's decoder
    for a in coco["annotations"]:
        img = coco["images"][a["image_id"] - 1]
        inst = cv2.imread(str(out / meta["frames"][a["image_id"] - 1]["files"]["instance"]), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(decode(a["segmentation"]), inst == a["instance_id"])
        assert (out / img["file_name"]).exists() and a["area"] == (inst == a["instance_id"]).sum()
        assert cats[a["category_id"]] == meta["instances"][a["instance_id"] - 1]["type"]
    pytest.importorskip("pycocotools.coco").COCO(str(out / "coco/annotations/instances_train.json"))


def test_events_h5_and_torch_dataset(rendered):
    h5py = pytest.importorskip("h5py")
    with h5py.File(rendered / "events/events.h5", "r") as f:
        x, y, t, p = (f[k][()] for k in ("x", "y", "t", "p"))
        assert f.attrs["width"] == 128 and f.attrs["t_unit"] == "us"
        assert len(f["frame_t"]) == 20
    assert len(t) > 0 and set(np.unique(p)) <= {-1, 1}
    assert x.max() < 128 and y.max() < 96 and np.all(np.diff(t) >= 0)
    pytest.importorskip("torch")
    from roadtwin_core.datasets.render_output import RenderDataset

    ds = RenderDataset(rendered)
    item = ds[1]
    assert len(ds) == 3 and item["image"].shape == (3, 64, 96) and item["semantic"].shape == (64, 96)
    assert item["normal"].shape == (3, 64, 96) and item["disparity"].dtype.is_floating_point


def test_dataset_module_imports_torch_lazily():
    code = "import sys, roadtwin_core.render, roadtwin_core.datasets.render_output; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


# --------------------------------------------------------------------------- preview.png
def test_preview_of_composed_town(town_stage, pm, tmp_path, renderer):
    """One perspective render beside the map; its camera is 2 m above a driving lane and sees a
    defect (checked with the renderer's own instance map of that camera)."""
    from PIL import Image

    from roadtwin_core.apps.compose.preview import write_preview
    from roadtwin_core.usd import load_town

    res = write_preview(tmp_path / "p.png", town_stage, pm=pm, title="t")
    assert res["note"] is None and res["spot"].defects_ahead >= 1
    w, h = Image.open(tmp_path / "p.png").size
    assert w > 2 * h                                               # render + map side by side
    cam = res["camera"]
    mesh = build_render_mesh(load_town(town_stage, looks=True))
    fr = one(renderer, mesh, cam, shade=False)
    assert (fr.instance > 0).sum() > 20
    assert (fr.semantic[-1] == mesh.classes.index("driving")).mean() > 0.3     # on a driving lane
    ground = mesh.vertices[:, 2][np.linalg.norm(mesh.vertices[:, :2] - cam.position[:2], axis=1) < 3].mean()
    assert 1.5 <= cam.position[2] - ground <= 2.5


def test_preview_without_a_renderer_shows_the_map_alone(town_stage, tmp_path):
    from PIL import Image

    from roadtwin_core.apps.compose.preview import write_preview

    bare = PluginManager(load_entry_points=False)
    bare.register(roadtwin_defects, name="defects")
    res = write_preview(tmp_path / "p.png", town_stage, pm=bare)
    assert res["camera"] is None and "no perspective view" in res["note"] and "warp" in res["note"]
    w, h = Image.open(tmp_path / "p.png").size
    assert w < 1.6 * h


# --------------------------------------------------------------------------- bad input
@pytest.fixture()
def earlier(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("earlier output")
    return out


def assert_untouched(out: Path) -> None:
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".out.")]


@pytest.mark.parametrize("kwargs, message", [
    ({"size": "0x0"}, "at least 1x1"),
    ({"size": "640by480"}, "WIDTHxHEIGHT"),
    ({"formats": "kitti,yolo", "stereo": True}, "unknown format 'yolo'"),
    ({"formats": "kitti"}, "add --stereo"),
    ({"weather": "snow"}, "unknown weather"),
    ({"renderer": "nope"}, "unknown renderer 'nope'"),
    ({"material": "marble"}, "roadMaterial"),
])
def test_bad_options(town_stage, pm, earlier, kwargs, message):
    with pytest.raises(RoadtwinError, match=message):
        run_render(town_stage, earlier, RenderOptions(frames=1, size=kwargs.pop("size", "16x12"), **kwargs), pm=pm)
    assert_untouched(earlier)


def test_bad_input_through_the_command(town_stage, pm, earlier):
    res = invoke(pm, [town_stage, "-o", earlier, "--size", "0x0"])
    assert isinstance(res.exception, RoadtwinError) and "at least 1x1" in str(res.exception)
    res = invoke(pm, [town_stage, "-o", earlier, "--size", "8x8", "--formats", "mmseg,png"])
    assert isinstance(res.exception, RoadtwinError) and "unknown format 'png'" in str(res.exception)
    assert_untouched(earlier)


def test_stage_without_cameras_or_poses(pm, tmp_path, earlier):
    from pxr import Sdf, Usd, UsdGeom

    from roadtwin_core.usd.stage import write_mesh

    path = tmp_path / "bare.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    root = UsdGeom.Xform.Define(stage, "/Town").GetPrim()
    stage.SetDefaultPrim(root)
    mesh = UsdGeom.Mesh.Define(stage, "/Town/seg")
    v, f = plane(half=10.0)
    write_mesh(mesh, v, f)
    mesh.GetPrim().CreateAttribute("roadtwin:segment:kind", Sdf.ValueTypeNames.Token).Set("driving")
    stage.GetRootLayer().Save()
    with pytest.raises(RoadtwinError, match="no cameras or poses"):
        run_render(path, earlier, RenderOptions(frames=1, size="16x12"), pm=pm)
    assert_untouched(earlier)


@pytest.mark.parametrize("dz, message", [(-1.0, "below the road surface"), (0.01, "inside geometry")])
def test_camera_inside_geometry(town_stage, pm, tmp_path, earlier, dz, message):
    pose = defect_poses(town_stage)[0]
    pose["position"][2] += dz - 1.6
    poses = tmp_path / "p.json"
    poses.write_text(json.dumps([pose]))
    with pytest.raises(RoadtwinError, match=message):
        run_render(town_stage, earlier, RenderOptions(frames=1, size="16x12", poses=poses), pm=pm)
    assert_untouched(earlier)


def test_renderer_refuses_cameras_in_geometry(renderer):
    rim = polygon((0.0, 0.0), 0.6, 6)
    town = build_render_mesh(scene([("driving", *road_with_holes(10.0, [rim]))], [("pothole", *pit(rim, 0.2))]))
    intr = Intrinsics.from_fov(16, 12, 60.0)
    with pytest.raises(RoadtwinError, match="camera 1 .* below the road surface"):
        renderer.render(town, [Camera(intr, look_from((3, 0, 1.5), 0, 0)), Camera(intr, look_from((3, 0, -0.5), 0, 0))])
    with pytest.raises(RoadtwinError, match="inside geometry: a surface 0.0"):
        renderer.render(town, [Camera(intr, look_from((3, 0, 0.001), 0, -0.3))])


def test_parse_size():
    assert parse_size("640x480") == (640, 480) and parse_size(" 8 X 6 ") == (8, 6)
    for bad in ("0x10", "10x0", "x", "-1x5", "99999x2"):
        with pytest.raises(RoadtwinError):
            parse_size(bad)
