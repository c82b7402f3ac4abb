"""The preview's in-memory town shows what the written stage shows: same triangles per label,
same materials (parsed from the stage's looks layer) bound to the same area, same st.
(USD stores points as float32: on 12 cm paint lines 100 m from the origin that is 1e-4 of the area.)"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadtwin_core.apps.compose.run import compose
from roadtwin_core.plugins import get_plugin_manager
from roadtwin_core.apps.compose.preview_scene import PREVIEW_TEXELS
from roadtwin_core.render import build_render_mesh
from roadtwin_core.usd.town_reader import load_town

REPO = Path(__file__).resolve().parents[2]
mip_levels = pytest.importorskip("roadtwin_warp_render.raycast").mip_levels


@pytest.fixture(scope="module")
def composed(tmp_path_factory):
    import roadtwin_core.apps.compose.run as composer

    captured = {}
    real = composer.write_preview

    def spy(path, stage, **kw):
        captured["town"] = kw.get("town")
        return real(path, stage, **kw)

    composer.write_preview = spy
    try:
        # a plugin manager of the caller's keeps the preview in this process, where the spy sees it
        res = compose(REPO / "stages" / "town.usda", tmp_path_factory.mktemp("pv") / "out", defects=40, seed=3,
                      executor="serial", pm=get_plugin_manager())
    finally:
        composer.write_preview = real
    return res, captured["town"]


def _per_material(mesh):
    """material short name -> (area, mean st, area-weighted mean z, material) (face-order free)."""
    tri = mesh.vertices[mesh.faces]
    e1, e2 = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    out = {}
    for k, m in enumerate(mesh.materials):
        sel = mesh.face_material == k
        if not sel.any():
            continue
        a = area[sel]
        out[m.name.rsplit("/", 1)[-1]] = (a.sum(), mesh.face_uv[sel].astype(np.float64).mean(axis=(0, 1)),
                                          (tri[sel, :, 2].mean(axis=1) * a).sum() / a.sum(), m)
    return out


def test_preview_town_matches_the_written_stage(composed):
    res, town = composed
    assert town is not None and (res.outdir / "preview.png").exists()
    scene = load_town(res.town, looks=True)
    scene.props = []                  # the preview draws the road, not the roadside world (layers/props.usda)
    ref = build_render_mesh(scene)
    behind_all = np.array([ref.vertices[:, 0].min() - 10.0, ref.vertices[:, 1].mean()])  # facing +x: all ahead
    spot = type("Spot", (), {"xy": behind_all, "heading": 0.0})()
    town.looks_layer = res.outdir / "layers" / "looks.usda"   # compose wrote it in a folder since renamed
    ours = town.view_mesh(spot, range_m=1e6)            # everything, with looks
    a, b = _per_material(ref), _per_material(ours)
    assert sorted(a) == sorted(b)
    for name in a:
        np.testing.assert_allclose(a[name][0], b[name][0], rtol=1e-4, err_msg=name)
        np.testing.assert_allclose(a[name][1], b[name][1], rtol=0, atol=1e-4, err_msg=name)
        np.testing.assert_allclose(a[name][2], b[name][2], rtol=0, atol=1e-4, err_msg=name)
        # the preview decodes textures at a smaller MIP level: the renderer's own box pyramid of
        # the full-size decode, at the preview's size
        for key in ("diffuse", "roughness", "normal"):
            full, small = getattr(a[name][3], key), getattr(b[name][3], key)
            assert (full is None) == (small is None), (name, key)
            if full is None:
                continue
            assert max(small.shape[:2]) <= PREVIEW_TEXELS and small.shape[:2] <= full.shape[:2]
            level = next(m for m in mip_levels(full) if m.shape == small.shape)
            np.testing.assert_allclose(small, level, rtol=0, atol=1e-6, err_msg=f"{name} {key}")
    # labels: the map mesh has the stage's triangles per class and per defect instance
    full = town.map_mesh()
    assert len(full.faces) == len(ref.faces)
    for cls in ref.classes:
        assert (np.asarray(full.classes)[full.face_class] == cls).sum() == \
            (np.asarray(ref.classes)[ref.face_class] == cls).sum(), cls
    assert np.bincount(full.face_instance).tolist() == np.bincount(ref.face_instance).tolist()


def test_view_wedge_keeps_everything_the_camera_sees(composed):
    """The preview's view mesh, culled to the camera's wedge, renders the same labels and depth
    as the whole town from that camera (the renderer, warp backend, on both meshes)."""
    from roadtwin_warp_render.renderer import WarpRenderer

    from roadtwin_core.apps.compose.preview import AHEAD_M, RENDER_HFOV_DEG, RENDER_SIZE, choose_spot, view_half_angle
    from roadtwin_core.render import Camera, Intrinsics, RenderParams, look_from

    res, town = composed
    town.looks_layer = res.outdir / "layers" / "looks.usda"
    spot = choose_spot(town.lanes(), np.array([[p.x, p.y] for p in town.placements]))
    whole = town.map_mesh()
    z = whole.vertices[np.linalg.norm(whole.vertices[:, :2] - spot.xy, axis=1) < 3, 2].mean()
    pitch = -np.arctan2(2.0, 0.5 * sum(AHEAD_M)) + np.radians(4.0)
    cam = Camera(Intrinsics.from_fov(160, 96, RENDER_HFOV_DEG), look_from((*spot.xy, z + 2.0), spot.heading, pitch))
    assert RENDER_SIZE[0] / RENDER_SIZE[1] == 160 / 96                 # same frustum as the preview's
    culled = town.view_mesh(spot, range_m=1e6, half_angle=view_half_angle(cam))
    assert len(culled.faces) < 0.8 * len(whole.faces)                  # it does cull
    params = RenderParams(backend="warp", shade=False)
    a = next(iter(WarpRenderer().render(whole, [cam], params)))
    b = next(iter(WarpRenderer().render(culled, [cam], params)))
    assert (a.face >= 0).mean() > 0.3
    np.testing.assert_array_equal(a.semantic, b.semantic)
    np.testing.assert_array_equal(a.instance, b.instance)
    np.testing.assert_allclose(a.depth, b.depth, rtol=1e-4, atol=1e-3)


def test_kernel_load_leaves_warps_settings_alone():
    """The renderer loads its kernels without precompiled headers (cheaper first compile) and
    puts warp's global setting back for everyone else."""
    import warp as wp

    from roadtwin_warp_render import raycast

    before = wp.config.use_precompiled_headers
    rs = raycast.RaycastScene(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), [[0, 1, 2]], [1], [0])
    assert wp.config.use_precompiled_headers == before
    t, _ = rs.cast(np.array([[0.2, 0.2, 1.0]]), np.array([[0.0, 0.0, -1.0]]))
    np.testing.assert_allclose(t, [1.0], atol=1e-6)
