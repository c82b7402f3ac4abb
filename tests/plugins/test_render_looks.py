"""Appearance is data: the warp renderer shows the UsdPreviewSurface materials and textures bound
in the stage. Stages here are built by hand (quads, PNGs, materials), rendered under a known sun
and checked against closed forms computed here: the texture's colour (sRGB decoded by the
formula below) times the Lambert factor of the renderer's documented light model, a checker's
cells where they project, the texture mean where the MIP level is the coarsest, a tilted normal
map's closed-form shading. Images are tiny.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

import roadtwin_warp_render
from roadtwin_core import PluginManager, RoadtwinError
from roadtwin_core.render import Camera, Intrinsics, RenderMesh, RenderParams, build_render_mesh, look_from, to_srgb8
from roadtwin_core.render.scene_look import MaterialLook
from roadtwin_core.usd import load_town
from roadtwin_core.usd.stage import apply_labels, new_stage, write_mesh

# Sun 45 degrees up: its mirror reflection is 45 degrees off the vertical, well outside the
# downward cameras' view (hfov <= 40 degrees), so with the test materials' low roughness (0.18:
# a narrow lobe) no pixel below carries sheen and the shading is Lambert alone.
SUN_EL, SUN_AZ = 45.0, 30.0


@pytest.fixture(scope="module")
def renderer():
    m = PluginManager(load_entry_points=False)
    m.register(roadtwin_warp_render, name="warp_render")
    return m.get("renderers", "warp")


def srgb_decode(c8) -> np.ndarray:
    c = np.asarray(c8, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def lambert(normal=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Irradiance factor of the clear preset on an unshadowed surface with this normal: sun
    colour times cos(incidence) plus the sky ambient (mean of zenith and horizon colour times
    ``ambient`` times (0.6 + 0.4 n_z)), as the renderer documents its light model."""
    rc = roadtwin_warp_render.renderer._rc()
    spec = rc.light_preset("clear")
    el, az = math.radians(SUN_EL), math.radians(SUN_AZ)
    sun = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    sky_up = (np.array(spec.sky_zenith) + np.array(spec.sky_horizon)) / 2
    return np.array(spec.sun_rgb) * max(n @ sun, 0.0) + sky_up * spec.ambient * (0.6 + 0.4 * n[2])


# ------------------------------------------------------------------------------------ stage building
def png(path: Path, rgb: np.ndarray) -> str:
    Image.fromarray(np.asarray(rgb, np.uint8)).save(path)
    return path.name


def checker(n: int, a, b, texels: int = 1) -> np.ndarray:
    """n x n cells of ``texels`` x ``texels``: cell (row, col) from the top-left is ``a`` when
    row + col is even."""
    img = np.empty((n, n, 3), np.uint8)
    rr, cc = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    img[(rr + cc) % 2 == 0] = a
    img[(rr + cc) % 2 == 1] = b
    return np.repeat(np.repeat(img, texels, axis=0), texels, axis=1)


def material(stage, path: str, diffuse=None, diffuse_color=None, roughness=0.18, rough_tex=None, normal_tex=None):
    """A UsdPreviewSurface material; textures read primvar ``st`` through a PrimvarReader."""
    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, f"{path}/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")

    def texture(name, file, raw, **inputs):
        t = UsdShade.Shader.Define(stage, f"{path}/{name}")
        t.CreateIdAttr("UsdUVTexture")
        t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
        t.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        t.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
        t.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
        if raw:
            t.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
        for k, v in inputs.items():
            t.CreateInput(k, Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*v))
        return t

    if diffuse is not None:
        t = texture("DiffuseTex", diffuse, False)
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            t.ConnectableAPI(), "rgb")
    else:
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse_color))
    if rough_tex is not None:
        t = texture("RoughTex", rough_tex, True)
        surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(t.ConnectableAPI(), "r")
    else:
        surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    if normal_tex is not None:
        t = texture("NormalTex", normal_tex, True, scale=(2, 2, 2, 1), bias=(-1, -1, -1, 0))
        surf.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(t.ConnectableAPI(), "rgb")
    return mat


def quad(stage, path: str, x0, x1, y0, y1, z=0.0, st_tile=4.0, face_varying=False, kind="driving"):
    """A two-triangle quad with world-planar st = xy / st_tile."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    mesh = UsdGeom.Mesh.Define(stage, path)
    write_mesh(mesh, v, np.array([[0, 1, 2], [0, 2, 3]]))
    st = (v[:, :2] / st_tile).astype(np.float32)
    pv = UsdGeom.PrimvarsAPI(mesh.GetPrim())
    if face_varying:
        corners = np.array([0, 1, 2, 0, 2, 3])
        pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
            Vt.Vec2fArray.FromNumpy(st[corners]))
    else:
        pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
            Vt.Vec2fArray.FromNumpy(st))
    if kind is not None:
        mesh.GetPrim().CreateAttribute("roadtwin:segment:kind", Sdf.ValueTypeNames.Token).Set(kind)
    return mesh


def bind(mesh, mat) -> None:
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)


A_RGB = (200, 120, 60)
CHECK_A, CHECK_B = (230, 230, 230), (30, 60, 120)


@pytest.fixture()
def two_quads(tmp_path):
    """Quad A (x < 0): solid A_RGB texture; quad B (x > 0): 4x4 checker of 4x4 texels, 1 m cells; a solid
    white marking strip 5 mm above quad A; textures under ``textures/`` next to the stage."""
    (tmp_path / "textures").mkdir()
    png(tmp_path / "textures/solid.png", np.full((4, 4, 3), A_RGB))
    png(tmp_path / "textures/checker.png", checker(4, CHECK_A, CHECK_B, texels=4))
    png(tmp_path / "textures/paint.png", np.full((2, 2, 3), 250))
    path = tmp_path / "town.usda"
    stage = new_stage(path, "Town")
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Town").GetPrim())
    UsdGeom.Scope.Define(stage, "/Town/Looks")
    ma = material(stage, "/Town/Looks/SolidA", diffuse="./textures/solid.png")
    mb = material(stage, "/Town/Looks/CheckerB", diffuse="./textures/checker.png")
    mp = material(stage, "/Town/Looks/Paint", diffuse="./textures/paint.png")
    bind(quad(stage, "/Town/Roads/a", -100.0, 0.0, -100.0, 100.0), ma)
    bind(quad(stage, "/Town/Roads/b", 0.0, 100.0, -100.0, 100.0), mb)
    mark = UsdGeom.Xform.Define(stage, "/Town/Markings/m0").GetPrim()
    mark.CreateAttribute("roadtwin:marking:type", Sdf.ValueTypeNames.Token).Set("solid")
    apply_labels(mark, ["lane_marking", "solid"])
    bind(quad(stage, "/Town/Markings/m0/dash0", -3.0, -2.85, -50.0, 50.0, z=0.005, kind=None), mp)
    stage.GetRootLayer().Save()
    return path


def render(renderer, stage_or_mesh, cam, **kw):
    mesh = stage_or_mesh if isinstance(stage_or_mesh, RenderMesh) else build_render_mesh(load_town(stage_or_mesh, looks=True))
    params = RenderParams(shadows=False, sun_elevation_deg=SUN_EL, sun_azimuth_deg=SUN_AZ, **kw)
    return next(iter(renderer.render(mesh, [cam], params))), mesh


def down_camera(x, y, h, size=32, hfov=40.0) -> Camera:
    return Camera(Intrinsics.from_fov(size, size, hfov), look_from((x, y, h), 0.0, -math.pi / 2))


def hit_points(fr, cam: Camera) -> np.ndarray:
    """World points the pixels see, from the depth map (independent of the shading)."""
    k = cam.intrinsics
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    pc = np.stack([(u - k.cx) / k.fx * fr.depth, (v - k.cy) / k.fy * fr.depth, fr.depth], axis=-1)
    return pc @ cam.rotation.T + cam.position


# ------------------------------------------------------------------------------------ tests
def test_solid_texture_times_lambert(renderer, two_quads):
    fr, _ = render(renderer, two_quads, down_camera(-20.0, 10.0, 2.0))
    expected = srgb_decode(A_RGB) * lambert()
    np.testing.assert_allclose(fr.rgb.reshape(-1, 3), np.tile(expected, (32 * 32, 1)), rtol=0.01)


def bilinear_repeat(img_linear: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Textbook bilinear texture lookup with repeat wrapping; st (0, 0) = the image's lower-left
    corner (USD), texel centres at half-integers."""
    h, w = img_linear.shape[:2]
    x, y = s * w - 0.5, (1 - t) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    i0, j0 = x0.astype(int) % w, y0.astype(int) % h
    i1, j1 = (i0 + 1) % w, (j0 + 1) % h
    return ((img_linear[j0, i0] * (1 - fx) + img_linear[j0, i1] * fx) * (1 - fy)
            + (img_linear[j1, i0] * (1 - fx) + img_linear[j1, i1] * fx) * fy)


def test_checker_bilinear_near_and_mean_far(renderer, two_quads):
    cam = down_camera(20.3, 10.2, 4.0)
    fr, _ = render(renderer, two_quads, cam)
    p = hit_points(fr, cam)
    # close up (9 cm pixels, 25 cm texels): the finest level, bilinearly magnified
    want = bilinear_repeat(srgb_decode(checker(4, CHECK_A, CHECK_B, texels=4)), p[..., 0] / 4.0,
                           p[..., 1] / 4.0) * lambert()
    np.testing.assert_allclose(fr.rgb, want, rtol=0.01, atol=1e-4)
    lo, hi = srgb_decode(CHECK_B) * lambert(), srgb_decode(CHECK_A) * lambert()
    assert (np.abs(fr.rgb - lo).max(-1) < 1e-3).sum() > 50 and (np.abs(fr.rgb - hi).max(-1) < 1e-2).sum() > 50
    # 600 m up with 16 px over 4 degrees: ~2.6 m a pixel, many texture repeats: the coarsest
    # MIP level, i.e. the texture's mean (in linear colour)
    far = down_camera(50.0, 0.0, 600.0, size=16, hfov=4.0)
    fr, _ = render(renderer, two_quads, far)
    mean = (srgb_decode(CHECK_A) + srgb_decode(CHECK_B)) / 2 * lambert()
    np.testing.assert_allclose(fr.rgb.reshape(-1, 3), np.tile(mean, (16 * 16, 1)), rtol=0.01)


def test_retextured_stage_renders_the_new_texture(renderer, two_quads):
    cam = down_camera(-20.0, 10.0, 2.0, size=8)
    before, _ = render(renderer, two_quads, cam)
    # 1) overwrite the PNG the material points to
    png(two_quads.parent / "textures/solid.png", np.full((4, 4, 3), (20, 200, 90)))
    fr, _ = render(renderer, two_quads, cam)
    np.testing.assert_allclose(fr.rgb[4, 4], srgb_decode((20, 200, 90)) * lambert(), rtol=0.01)
    # 2) point the material at another file (what re-texturing in another tool writes)
    png(two_quads.parent / "textures/mine.png", np.full((3, 5, 3), (90, 10, 240)))
    stage = Usd.Stage.Open(str(two_quads))
    UsdShade.Shader(stage.GetPrimAtPath("/Town/Looks/SolidA/DiffuseTex")).GetInput("file").Set("./textures/mine.png")
    stage.GetRootLayer().Save()
    fr, _ = render(renderer, two_quads, cam)
    np.testing.assert_allclose(fr.rgb[4, 4], srgb_decode((90, 10, 240)) * lambert(), rtol=0.01)
    assert np.abs(before.rgb[4, 4] - fr.rgb[4, 4]).max() > 0.1


def test_lane_marking_pixels_are_labelled(renderer, two_quads):
    cam = down_camera(-2.925, 0.0, 2.0, size=48)
    fr, mesh = render(renderer, two_quads, cam)
    p = hit_points(fr, cam)
    on_paint = (np.abs(p[..., 0] + 2.925) < 0.05)
    off_paint = (np.abs(p[..., 0] + 2.925) > 0.12)
    assert on_paint.sum() > 20 and off_paint.sum() > 200
    lm = mesh.classes.index("lane_marking")
    assert (fr.semantic[on_paint] == lm).all()
    assert (fr.semantic[off_paint] == mesh.classes.index("driving")).all()
    np.testing.assert_allclose(fr.rgb[on_paint], np.tile(srgb_decode((250,) * 3) * lambert(), (on_paint.sum(), 1)),
                               rtol=0.01)
    assert [m.kind for m in load_town(two_quads).markings] == ["solid"]


def test_normal_map_tilts_the_shading_normal(renderer, tmp_path):
    """A constant tangent-space normal (sin a, 0, cos a) on world-planar st (s along +X) is the
    world normal (sin a, 0, cos a): the shading is Lambert with that normal."""
    a = math.radians(-25.0)                 # tilted away from the sun (no sheen towards the camera)
    n = np.array([math.sin(a), 0.0, math.cos(a)])
    png(tmp_path / "n.png", np.full((4, 4, 3), np.rint((n + 1) / 2 * 255)))
    png(tmp_path / "grey.png", np.full((4, 4, 3), 128))
    path = tmp_path / "t.usda"
    stage = new_stage(path, "Town")
    UsdGeom.Xform.Define(stage, "/Town")
    mat = material(stage, "/Town/Looks/Bumpy", diffuse="./grey.png", normal_tex="./n.png")
    bind(quad(stage, "/Town/Roads/a", -50.0, 50.0, -50.0, 50.0), mat)
    stage.GetRootLayer().Save()
    fr, _ = render(renderer, path, down_camera(0.0, 0.0, 3.0, size=8))
    n8 = np.rint((n + 1) / 2 * 255) / 255 * 2 - 1
    np.testing.assert_allclose(fr.rgb.reshape(-1, 3), np.tile(srgb_decode((128,) * 3) * lambert(n8), (64, 1)),
                               rtol=0.01)


def test_roughness_texture_and_face_varying_st(renderer, tmp_path):
    """Roughness from a texture's r channel renders like the same constant; faceVarying st like
    vertex st; a camera at the sun's mirror direction sees the smoother surface brighter."""
    png(tmp_path / "r.png", np.full((2, 2, 3), 128))           # 128 / 255 = 0.502 (raw)
    png(tmp_path / "c.png", checker(4, CHECK_A, CHECK_B, texels=4))
    path = tmp_path / "t.usda"
    stage = new_stage(path, "Town")
    UsdGeom.Xform.Define(stage, "/Town")
    tex = material(stage, "/Town/Looks/RoughTex", diffuse="./c.png", rough_tex="./r.png")
    const = material(stage, "/Town/Looks/RoughConst", diffuse="./c.png", roughness=128 / 255)
    smooth = material(stage, "/Town/Looks/Smooth", diffuse="./c.png", roughness=0.25)
    bind(quad(stage, "/Town/Roads/a", -50.0, 50.0, -50.0, 50.0), tex)
    bind(quad(stage, "/Town/Roads/b", -50.0, 50.0, -50.0, 50.0, z=-10.0, face_varying=True), const)
    bind(quad(stage, "/Town/Roads/c", -50.0, 50.0, -50.0, 50.0, z=-20.0), smooth)
    stage.GetRootLayer().Save()
    # looking at the sun's mirror reflection: towards the sun's azimuth, down at its elevation
    el, az = math.radians(SUN_EL), math.radians(SUN_AZ)
    d = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])
    frames = []
    for z, path_ in ((0.0, "a"), (-10.0, "b"), (-20.0, "c")):
        town = load_town(path, looks=True)
        town.roads = [r for r in town.roads if r.path.endswith("/" + path_)]
        pos = np.array([0.3, 0.2, z]) - 4.0 * d
        cam = Camera(Intrinsics.from_fov(16, 16, 30.0), look_from(pos, math.atan2(d[1], d[0]), -el))
        frames.append(render(renderer, build_render_mesh(town), cam)[0].rgb)
    np.testing.assert_allclose(frames[0], frames[1], rtol=2e-3, atol=1e-4)
    assert frames[2].max() > 2.0 * frames[1].max()


def test_missing_texture_and_unbound_mesh(renderer, tmp_path):
    path = tmp_path / "t.usda"
    stage = new_stage(path, "Town")
    UsdGeom.Xform.Define(stage, "/Town")
    quad(stage, "/Town/Roads/plain", -50.0, 50.0, -50.0, 50.0)     # no material
    stage.GetRootLayer().Save()
    # the default grey is rough (0.5: a broad sheen lobe): view it with the sun behind the camera
    cam = Camera(Intrinsics.from_fov(8, 8, 20.0), look_from((0.0, 0.0, 1.0), math.radians(SUN_AZ + 180), -0.5))
    fr, mesh = render(renderer, path, cam)
    np.testing.assert_allclose(fr.rgb.reshape(-1, 3), np.tile(0.18 * lambert(), (64, 1)), rtol=0.01)
    mat = material(stage, "/Town/Looks/Lost", diffuse="./textures/nowhere.png")
    bind(stage.GetPrimAtPath("/Town/Roads/plain"), mat)
    stage.GetRootLayer().Save()
    with pytest.raises(RoadtwinError, match=r"material /Town/Looks/Lost: texture file '\./textures/nowhere\.png'"):
        load_town(path, looks=True)
    assert load_town(path).roads[0].material is None       # physics and planning never read looks


def test_render_mesh_npz_keeps_looks(renderer, two_quads, tmp_path):
    mesh = build_render_mesh(load_town(two_quads, looks=True))
    mesh.save_npz(tmp_path / "m.npz")
    back = RenderMesh.load_npz(tmp_path / "m.npz")
    assert [m.name for m in back.materials] == [m.name for m in mesh.materials]
    cam = down_camera(1.0, 1.0, 2.0, size=16)
    a, _ = render(renderer, mesh, cam)
    b, _ = render(renderer, back, cam)
    np.testing.assert_allclose(a.rgb, b.rgb, rtol=1e-5, atol=1e-6)


def test_road_material_variant_selects_the_binding(renderer, tmp_path):
    """``--material`` picks a variant of the root's roadMaterial set (in memory, file unchanged)."""
    png(tmp_path / "red.png", np.full((2, 2, 3), (200, 20, 20)))
    png(tmp_path / "blue.png", np.full((2, 2, 3), (20, 20, 200)))
    path = tmp_path / "t.usda"
    stage = new_stage(path, "Town")
    root = UsdGeom.Xform.Define(stage, "/Town").GetPrim()
    red = material(stage, "/Town/Looks/Red", diffuse="./red.png")
    blue = material(stage, "/Town/Looks/Blue", diffuse="./blue.png")
    mesh = quad(stage, "/Town/Roads/a", -50.0, 50.0, -50.0, 50.0)
    vs = root.GetVariantSets().AddVariantSet("roadMaterial")
    for name, mat in (("red", red), ("blue", blue)):
        vs.AddVariant(name)
        vs.SetVariantSelection(name)
        with vs.GetVariantEditContext():
            bind(mesh, mat)
    vs.SetVariantSelection("red")
    stage.GetRootLayer().Save()
    cam = down_camera(0.0, 0.0, 2.0, size=4)
    for choice, rgb in ((None, (200, 20, 20)), ("blue", (20, 20, 200))):
        town = load_town(path, looks=True, variants={"roadMaterial": choice} if choice else None)
        fr, _ = render(renderer, build_render_mesh(town), cam)
        np.testing.assert_allclose(fr.rgb[2, 2], srgb_decode(rgb) * lambert(), rtol=0.01)
    with pytest.raises(RoadtwinError, match="roadMaterial variant 'marble' is not one of"):
        load_town(path, looks=True, variants={"roadMaterial": "marble"})
    saved = Usd.Stage.Open(str(path))
    assert saved.GetPrimAtPath("/Town").GetVariantSets().GetVariantSet("roadMaterial").GetVariantSelection() == "red"


def test_frames_finished_in_batches_each_show_their_own_look(renderer, two_quads):
    """``render_finished`` (what ``render --device cuda`` runs) queues a batch's material looks,
    lanes and sensors in one upload and the next batch before the caller takes this one's
    frames: each frame must still show its own look — the solid texture times Lambert times that
    frame's diffuse scale, tone-mapped (closed form) — and its bytes must not depend on the batch
    it rendered in (frames rendered one call each)."""
    mesh = build_render_mesh(load_town(two_quads, looks=True))
    n = len(mesh.materials)
    solid = next(i for i, m in enumerate(mesh.materials) if m.name.endswith("SolidA"))
    cam = down_camera(-20.0, 10.0, 2.0, size=16)
    params = RenderParams(shadows=False, sun_elevation_deg=SUN_EL, sun_azimuth_deg=SUN_AZ)
    factors = [0.3, 0.5, 0.7, 0.9, 1.1]

    def request(f):
        scale = np.ones((n, 3))
        scale[solid] = f
        return {"camera": cam, "params": params, "effects": None, "labels": {"label_distance": 1e3},
                "look": MaterialLook(np.arange(n), scale)}

    batched = list(renderer.render_finished(mesh, [request(f) for f in factors], params, batch=2))
    assert len(batched) == len(factors)
    for f, frame in zip(factors, batched):
        want = to_srgb8((srgb_decode(A_RGB) * lambert() * f)[None, None].astype(np.float32))[0, 0]
        assert np.abs(frame["rgb8"].astype(int) - want.astype(int)).max() <= 1, (f, frame["rgb8"][8, 8], want)
        alone = next(iter(renderer.render_finished(mesh, [request(f)], params, batch=1)))
        for key in ("rgb8", "labels", "depth", "instance"):
            np.testing.assert_array_equal(frame[key], alone[key])
