"""A photo pothole keeps its photo's look in the town (issue 22 item 1; plugins/roadtwin_photo,
plugins/roadtwin_warp_render).

A synthetic photo through the survey rig: a flat grey road (sRGB 110), a dark disc on it (sRGB
50, labelled pothole) and, for the fade-band test, a white stripe of lane paint touching the
disc. The independent reference is the photo itself: the disc's linear luminance is
``decode(50) / decode(110)`` of the road's (IEC 61966-2-1), whatever the pipeline does.

- The texture's fade band (outside the label) shows no paint: a renderer draws the decal opaque,
  so paint there became a white rim in the town (before: the band held the paint at 4x the
  road's luminance).
- Reconstruct -> compose (``--library``) -> warp render, seen from straight above: the rendered
  floor of the pothole over the rendered road matches the photo's albedo ratio put through the
  renderer's documented light model (Lambert sun + sky ambient, plus the sun's specular lobe of a
  dielectric, F0 = 0.04, which does not scale with albedo: from above it lifts a 0.20 ratio to
  about 0.30). A double or missing sRGB decode, an albedo scaled on the wrong reference or st
  sampling the patch's border would each move it by far more than the tolerance.
- The props layer's terrain (8 cm under the road) does not show through a deeper pothole's
  floor: it is cut away under the paved surface (roadtwin_core/town/terrain.py; before, grid
  triangles partly under the road were kept whole and the terrain showed in the pothole).
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import triangle
from pxr import Usd

import roadtwin_warp_render
from photo_scene import CLASSES, H, SURVEY, W, save_pair
from roadtwin_core import ComposeRules, PluginManager, RoadSegment, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.render import Camera, Intrinsics, RenderParams, build_render_mesh, look_from
from roadtwin_core.usd import load_town, write_layout
from roadtwin_photo import PhotoDefects

ROAD, HOLE, PAINT = 110, 50, 240          # sRGB grey levels of the photo
CENTRE, RADIUS = (7.0, 0.0), 0.35         # the disc on the road (m, rig frame)
Y = np.array([0.2126, 0.7152, 0.0722])


def decode(c8) -> np.ndarray:
    c = np.asarray(c8, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def disc_photo(paint: bool):
    """The road seen through the survey rig at the train frames' size: the disc (label 3) and,
    when ``paint``, a 15 cm white stripe along the road touching the disc's left side."""
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    xy, ok = SURVEY.backproject(uu.ravel(), vv.ravel(), W, H)
    x, y = xy[:, 0].reshape(H, W), xy[:, 1].reshape(H, W)
    ok = ok.reshape(H, W)
    disc = ok & (np.hypot(x - CENTRE[0], y - CENTRE[1]) <= RADIUS)
    grey = np.full((H, W), ROAD, np.uint8)
    if paint:
        grey[ok & (y > CENTRE[1] + RADIUS) & (y <= CENTRE[1] + RADIUS + 0.15)] = PAINT
    grey[disc] = HOLE
    return np.dstack([grey] * 3), np.where(disc, 3, 1).astype(np.uint8)


def reconstruct(folder, paint: bool):
    image, label = disc_photo(paint)
    img = save_pair(folder, "frame", image, label)
    res = PhotoDefects().run({"images": [img], "labels": folder / "labels", "classes": CLASSES, "rig": SURVEY,
                              "license": "CC0 (made by the test)"})
    assert len(res.instances) == 1
    return res


def test_fade_band_shows_no_paint_beside_the_label(tmp_path):
    patch = reconstruct(tmp_path, paint=True).instances[0].patch
    lum = decode(patch.albedo[..., :3]) @ Y
    alpha = patch.albedo[..., 3]
    band = (alpha > 0) & (alpha < 255)
    road = 0.12                                           # PatchParams.road_albedo: the ring's luminance
    assert band.sum() > 50
    assert lum[band].max() <= 1.5 * road * 1.05, lum[band].max()          # the paint would be ~4x
    assert np.median(lum[alpha == 0]) == pytest.approx(road, rel=0.05)   # the band ends on plain road
    core = cv2.erode(patch.footprint.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert np.median(lum[core]) / road == pytest.approx(decode(HOLE) / decode(ROAD), rel=0.05)   # the hole stays


@pytest.fixture(scope="module")
def disc_library(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("disc")
    PhotoDefects().write(reconstruct(tmp / "photos", paint=False), tmp / "lib")
    return tmp


def render_from_above(tmp, props: str):
    """Compose a 30 x 7 m road with the disc library (potholes only), render a 3 m high
    downward view of the placed photo pothole, sun 60 deg up behind the camera. Returns the
    frame, the world xy of each pixel's hit, the placement (x, y, scale) and the mesh's classes."""
    poly = np.array([[0, 0], [30, 0], [30, 7], [0, 7]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
    seg = RoadSegment("lane", "driving", t["vertices"], t["triangles"], np.array([[0, 3.5], [30, 3.5]]))
    layout = tmp / f"road_{props}.usda"
    write_layout(TownLayout("Town", [seg], ComposeRules(defect_count=8, seed=3, surface="flat",
                                                          type_weights={"pothole": 1.0}, models_per_type=1)), layout)
    done = compose(layout, tmp / f"town_{props}", library_dir=tmp / "lib", preview=False, executor="serial",
                   props=props)
    stage = Usd.Stage.Open(str(done.town))
    placed = [(p.GetAttribute("roadtwin:defect:poseXYYaw").Get(), p.GetAttribute("roadtwin:defect:scale").Get())
              for p in stage.GetPrimAtPath("/Town/Defects").GetChildren()
              if p.GetAttribute("roadtwin:defect:model").Get().startswith("lib_frame_")]
    assert placed
    (x, y, _), scale = placed[0]
    manager = PluginManager(load_entry_points=False)
    manager.register(roadtwin_warp_render, name="warp_render")
    cam = Camera(Intrinsics.from_fov(96, 96, 40.0), look_from((x, y, 3.0), 0.0, -math.pi / 2))
    params = RenderParams(sun_elevation_deg=60.0, sun_azimuth_deg=180.0, shadows=True)
    mesh = build_render_mesh(load_town(done.town, looks=True))
    fr = next(iter(manager.get("renderers", "warp").render(mesh, [cam], params)))
    k = cam.intrinsics
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    pc = np.stack([(u - k.cx) / k.fx * fr.depth, (v - k.cy) / k.fy * fr.depth, fr.depth], axis=-1)
    world = pc @ cam.rotation.T + cam.position
    return fr, world, (x, y, float(scale[0])), mesh.classes


def radiance(albedo: float, roughness: float, sun_el_deg: float) -> float:
    """Luminance of a flat, unshadowed grey surface seen from straight above under the clear
    preset, by the light model ``plugins/roadtwin_warp_render/raycast.py`` documents: albedo x
    (sun x cos + sky ambient x (0.6 + 0.4 n_z)) + Schlick(F0 0.04) x sun x normalized
    Blinn-Phong lobe (exponent 2 / r^4 - 2) with Kelemen visibility."""
    spec = roadtwin_warp_render.renderer._rc().light_preset("clear")
    el = math.radians(sun_el_deg)
    sun_dir, view = np.array([-math.cos(el), 0.0, math.sin(el)]), np.array([0.0, 0.0, 1.0])
    sun, ambient = float(np.dot(spec.sun_rgb, Y)), float(np.dot(spec.sky_zenith, Y) + np.dot(spec.sky_horizon, Y)) / 2
    ndl = sun_dir[2]
    h = (sun_dir + view) / np.linalg.norm(sun_dir + view)
    alpha = max(roughness ** 2, 0.03)
    shin = min(max(2 / alpha ** 2 - 2, 1.0), 2000.0)
    vdh = max(float(view @ h), 0.05)
    fresnel = 0.04 + 0.96 * (1 - vdh) ** 5
    lobe = (shin + 2) / 8 * float(h[2]) ** shin / vdh ** 2 * ndl
    return albedo * (sun * ndl + ambient * spec.ambient) + fresnel * sun * lobe


def test_dark_disc_renders_as_dark_as_in_its_photo(disc_library):
    fr, world, (x, y, s), _ = render_from_above(disc_library, "none")
    r = np.hypot(world[..., 0] - x, world[..., 1] - y)
    lum = fr.rgb @ Y
    floor = r <= 0.4 * RADIUS * s                          # inside the walls (they span 0.35 r_eq)
    road = (r >= 1.6 * RADIUS * s) & (r <= 2.4 * RADIUS * s)
    assert floor.sum() > 40 and road.sum() > 300
    ratio = np.median(lum[floor]) / np.median(lum[road])
    # the reference: the photo's albedos (road scaled to the town's asphalt, 0.12) and the
    # roughness each surface carries (the patch's map inside the label, the town's asphalt map)
    lib = disc_library / "lib" / "textures"
    rough_floor = np.median(cv2.imread(str(next(lib.glob("*_roughness.png"))), cv2.IMREAD_GRAYSCALE)[40:-40, 40:-40]) / 255
    town = disc_library / "town_none" / "textures" / "asphalt_worn_roughness.png"
    rough_road = np.median(cv2.imread(str(town), cv2.IMREAD_GRAYSCALE)) / 255
    road_albedo = float(np.median(decode(cv2.imread(str(town).replace("roughness", "diffuse"))[..., ::-1]) @ Y))
    want = (radiance(0.12 * decode(HOLE) / decode(ROAD), rough_floor, 60.0)
            / radiance(road_albedo, rough_road, 60.0))
    assert ratio == pytest.approx(want, abs=0.03), (ratio, want, decode(HOLE) / decode(ROAD))


def test_terrain_does_not_show_through_a_deep_pothole(disc_library):
    fr, world, (x, y, s), classes = render_from_above(disc_library, "default")
    r = np.hypot(world[..., 0] - x, world[..., 1] - y)
    inside = (r <= 0.6 * RADIUS * s) & (fr.depth > 0)
    assert inside.sum() > 100
    terrain = inside & (fr.semantic == classes.index("terrain"))
    assert not terrain.any(), f"terrain in {int(terrain.sum())} of {int(inside.sum())} px of the pothole"
