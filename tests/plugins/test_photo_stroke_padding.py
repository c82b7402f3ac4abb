"""A photo-made crack's albedo is its strokes' dark core, edge-padded, so its thin stroke mesh keeps
the crack's contrast in every MIP level (issue 22: the strokes, 1-3 texels across, averaged with
the road colour beside them and rendered nearly invisible where they were labelled crack)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from photo_scene import SURVEY
from roadtwin_photo.patch import PatchParams, make_patch
from roadtwin_photo.seamless import REC709, srgb_to_linear
from roadtwin_photo.strokes import pad_from_footprint, stroke_core
from roadtwin_warp_render.textures import mip_levels
from test_photo_crack_strokes import Y_ARMS, render_strokes


def _nearest_distance_ok(padded_ids: np.ndarray, foot: np.ndarray) -> None:
    """Each texel's padded id names a footprint texel at the least distance (a brute-force k-d tree)."""
    rows, cols = np.nonzero(foot)
    dist, _ = cKDTree(np.column_stack([rows, cols])).query(np.argwhere(np.ones_like(foot)))
    src = np.column_stack(np.divmod(padded_ids.ravel(), foot.shape[1]))
    assert foot[src[:, 0], src[:, 1]].all()
    got = np.hypot(*(src - np.argwhere(np.ones_like(foot))).T)
    np.testing.assert_allclose(got, dist, atol=1e-9)


def test_padding_copies_the_nearest_footprint_texel():
    rng = np.random.default_rng(3)
    foot = np.zeros((40, 50), bool)
    foot[rng.integers(0, 40, 25), rng.integers(0, 50, 25)] = True
    ids = np.arange(foot.size).reshape(foot.shape)
    padded = pad_from_footprint(ids, foot)
    assert np.array_equal(padded[foot], ids[foot])
    _nearest_distance_ok(padded, foot)
    rgba = np.dstack([ids % 256] * 4).astype(np.uint8)              # channels ride along
    assert np.array_equal(pad_from_footprint(rgba, foot)[..., 0], rgba[..., 0][divmod(padded, 50)])


def test_a_padded_stroke_keeps_its_value_in_every_mip_level():
    """A 2-texel stroke of value D on road R: a 4x4 box level over it averages (2D + 2R) / 4
    unpadded, exactly D padded."""
    img = np.full((16, 16), 100.0)
    foot = np.zeros((16, 16), bool)
    foot[:, 4:6] = True
    img[foot] = 20.0
    level2 = lambda a: a.reshape(4, 4, 4, 4).mean(axis=(1, 3))     # noqa: E731
    assert level2(img)[:, 1] == pytest.approx(np.full(4, (2 * 20 + 2 * 100) / 4))
    assert np.all(level2(pad_from_footprint(img, foot)) == 20.0)


def _stroke_contrast(albedo: np.ndarray, foot: np.ndarray, k: int, road: float) -> float:
    """Weber contrast to ``road`` (linear luminance) of the texels a lookup on the stroke mesh
    reads in MIP level k of the renderer's own pyramid: those holding a footprint texel."""
    lum = srgb_to_linear(albedo[..., :3]) @ REC709
    on = mip_levels(foot[..., None].astype(np.float32))[k][..., 0] > 0
    return 1.0 - float(mip_levels(lum[..., None])[k][..., 0][on].mean()) / road


def test_stroke_core_is_the_darkest_texel_across_the_label():
    """A label 3 texels wide over a crack 1 texel wide: the core is the crack's column."""
    lum = np.tile(np.array([0.5, 0.5, 0.3, 0.1, 0.25, 0.5, 0.5]), (20, 1))
    foot = np.zeros_like(lum, bool)
    foot[:, 2:5] = True
    core = stroke_core(lum, foot, 1)
    assert np.array_equal(np.flatnonzero(core.any(axis=0)), [3]) and core[:, 3].all()
    assert np.array_equal(stroke_core(lum, foot, 0), foot)


def test_photo_crack_strokes_keep_their_contrast_in_coarser_mip_levels():
    """A Y crack (3 cm strokes of grey 50 on road 110) photographed through the survey rig and
    reconstructed: its texture's contrast to the road (scaled to the town's asphalt, linear
    luminance 0.12: road_albedo) is the crack's own, 1 - lin(50) / lin(110) (closed form: the
    strokes' dark core, not the label's blend with the road), and stays so (within 2 %) in the
    MIP levels a survey camera samples (1-4: 2-16 texels across). The unpadded texture
    (crack_strokes=false: the same photo texture with its fade band) loses half of its
    contrast by level 2."""
    image, label = render_strokes(Y_ARMS)
    params = PatchParams()
    padded = make_patch(image, label == 2, SURVEY, "crack", params, seed=1)
    plain = make_patch(image, label == 2, SURVEY, "crack", PatchParams(crack_strokes=False), seed=1)
    assert np.array_equal(padded.footprint, plain.footprint)
    foot = padded.footprint
    assert np.all(padded.albedo[..., 3] == 255)
    crack = 1.0 - float(srgb_to_linear(np.array([50.0]))[0] / srgb_to_linear(np.array([110.0]))[0])
    c0 = _stroke_contrast(padded.albedo, foot, 0, params.road_albedo)
    assert c0 == pytest.approx(crack, abs=0.02)
    for k in (1, 2, 3, 4):
        assert _stroke_contrast(padded.albedo, foot, k, params.road_albedo) >= 0.98 * c0, k
    plain0 = _stroke_contrast(plain.albedo, foot, 0, params.road_albedo)
    assert plain0 < 0.9 * crack                                      # the label's mean: crack and road
    assert _stroke_contrast(plain.albedo, foot, 2, params.road_albedo) < 0.6 * plain0
