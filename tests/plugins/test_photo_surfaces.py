"""Road surfaces from photos (plugins/roadtwin_photo/surfaces.py, ``reconstruct photo-surfaces``,
``compose --road-textures``):

- on a real train frame, the written tile repeats without a seam: the mean absolute luminance
  step across its wrap is like the steps just inside it (measured here on the PNG), while the
  same window cut without blending shows a seam several times stronger;
- no period at the window's size: a window smaller than the 4 m tile, repeated k x k (the old
  output, ``quilt=false``), correlates 1.0 with itself a window further on (closed form); the
  quilted tile of the same frame far less, its wrap still seamless; toroidal image quilting of a
  synthetic exemplar likewise, keeping its mean and contrast; the minimum-error boundary cut is
  the least of all paths (brute force);
- back-projection scale and orientation: a road painted with known periods (25 cm along travel,
  40 cm across), seen through the survey rig, comes back with exactly those periods in texels
  of ``ST_TILE_M / size`` (FFT peak), travel along the texture's columns;
- ``compose --road-textures`` adds each material as a ``roadMaterial`` variant, the stage
  validates, the variant binds the lanes to it, ``--road-material`` selects it;
- bad input is one line, exit 2: an image without its label, a frame with no clean road area,
  (through the command); an unknown ``--road-material``, a folder without ``materials.json``
  (an error before any work: the command prints it as one line like any RoadtwinError).
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from pxr import Usd, UsdShade

from cli_run import one_line, run_cli
from photo_scene import SURVEY, H, W, save_pair
from lane_layout import write_lane_layout
from roadtwin_core import RoadtwinError
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.looks import ST_TILE_M
from roadtwin_core.usd import validate_stage
from roadtwin_photo.quilting import min_cut_path, quilt_torus
from roadtwin_photo.surfaces import PhotoSurfaces, PhotoSurfacesParams

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "tests/data/road_defects_br_tiny/train"
FRAME = TINY / "images/917067_RS_290_290RS294095_18785.jpg"
BR = {"classes": {2: ("crack", "crack"), 3: ("pothole", "pothole")}, "road_classes": {1: "ego_lane"},
      "rig": SURVEY}
# the tiny frames are 512x320: a pixel covers twice the road of a full-size one
FAST = dict(size=256, max_gsd_m=0.05)


@pytest.fixture(scope="module")
def real_materials(tmp_path_factory):
    out = tmp_path_factory.mktemp("surfaces") / "materials"
    rec = PhotoSurfaces()
    result = rec.run({**BR, "images": [FRAME], "labels": TINY / "labels"}, PhotoSurfacesParams(count=1, **FAST))
    rec.write(result, out)
    return out


def _luminance(bgr: np.ndarray) -> np.ndarray:
    return bgr[..., ::-1].astype(np.float64) @ [0.299, 0.587, 0.114]


def _seam_over_inside(lum: np.ndarray, axis: int) -> float:
    """Mean |step| across the wrap / mean |step| between the last tenth's neighbours."""
    n = lum.shape[axis]
    last = np.take(lum, range(n - n // 10, n), axis=axis)
    inside = np.abs(np.diff(last, axis=axis)).mean()
    seam = np.abs(np.take(lum, 0, axis=axis) - np.take(lum, n - 1, axis=axis)).mean()
    return seam / inside


def _shift_correlation(lum: np.ndarray, lag: int, axis: int) -> float:
    """Pearson correlation of the image with itself moved ``lag`` texels on (wrapping)."""
    return float(np.corrcoef(lum.ravel(), np.roll(lum, lag, axis=axis).ravel())[0, 1])


def test_real_frame_tile_has_no_seam(real_materials):
    meta = json.loads((real_materials / "materials.json").read_text())
    rec = meta["materials"][0]
    assert rec["frame"] == str(FRAME) and "MIT License" in rec["license"] and rec["source"].startswith("photo")
    diffuse = cv2.imread(str(real_materials / rec["diffuse"]))
    assert diffuse.shape[:2] == (FAST["size"],) * 2 and rec["repeats"] == 1 and "quilting" in rec["synthesis"]["method"]
    lum = _luminance(diffuse)
    for axis in (0, 1):
        assert 0.5 < _seam_over_inside(lum, axis) < 1.5, (axis, rec["seam_ratio"])
    # the same window without blending: its wrap is a visible seam (the measure can fail)
    assert max(rec["seam_ratio_unblended"].values()) > 2.0
    assert cv2.imread(str(real_materials / rec["roughness"]), cv2.IMREAD_UNCHANGED).ndim == 2
    normal = cv2.imread(str(real_materials / rec["normal"]))[..., ::-1].astype(float) / 127.5 - 1
    assert np.all(normal[..., 2] > 0.3) and abs(np.linalg.norm(normal, axis=-1).mean() - 1) < 0.02


def test_no_band_at_the_window_period(real_materials, tmp_path):
    """The old output (the window repeated k x k) correlates 1.0 with itself a window on; the
    quilted tile of the same frame does not, and its albedo is the old one's."""
    rec = PhotoSurfaces()
    old = rec.run({**BR, "images": [FRAME], "labels": TINY / "labels"},
                  PhotoSurfacesParams(count=1, quilt=False, **FAST)).surfaces[0]
    k = old.record["repeats"]
    assert k >= 2                                            # this frame's clean window is smaller than 4 m
    lag = FAST["size"] // k
    meta = json.loads((real_materials / "materials.json").read_text())["materials"][0]
    assert meta["window_m"] == pytest.approx(ST_TILE_M / k)
    new = _luminance(cv2.imread(str(real_materials / meta["diffuse"])))
    old_lum = old.tile[..., :3].astype(np.float64) @ [0.299, 0.587, 0.114]
    for axis in (0, 1):
        assert _shift_correlation(old_lum, lag, axis) > 0.99
        assert _shift_correlation(new, lag, axis) < 0.5, (axis, meta["window_period_correlation"])
    assert new.mean() == pytest.approx(old_lum.mean(), rel=0.05)


def _exemplar(side: int, seed: int = 0) -> np.ndarray:
    """Asphalt-like: fine grain, a few dark stains and a light streak, grey around 110."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    img = 110 + 14 * gaussian_filter(rng.normal(size=(side, side)), 1.2) / 0.23
    yy, xx = np.mgrid[0:side, 0:side]
    for cy, cx, r in rng.uniform([0, 0, 4], [side, side, 9], size=(6, 3)):
        img -= 25 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))
    img += 12 * np.exp(-((yy - side * 0.3) ** 2) / 20.0)
    return np.repeat(img[..., None], 3, axis=2)


def test_quilting_removes_the_window_period():
    """A 128-texel window tiled 2 x 2 correlates 1.0 at a lag of 128 (closed form: exact copies);
    quilted into 256 texels from the same window, it correlates little there, wraps without a
    seam and keeps the window's mean and contrast."""
    window = _exemplar(144)
    naive = np.tile(window[:128, :128], (2, 2, 1))[..., 0]
    quilted = quilt_torus([window], 256, 32, np.random.default_rng(1))
    assert quilted.shape == (256, 256, 3)
    lum = quilted[..., 0].astype(np.float64)
    for axis in (0, 1):
        assert _shift_correlation(naive, 128, axis) > 0.999
        assert abs(_shift_correlation(lum, 128, axis)) < 0.2
        assert 0.6 < _seam_over_inside(lum, axis) < 1.5
    assert lum.mean() == pytest.approx(window.mean(), rel=0.02)
    assert lum.std() == pytest.approx(window.std(), rel=0.25)
    assert np.array_equal(quilt_torus([window], 256, 32, np.random.default_rng(1)), quilted)


def test_min_cut_is_the_least_path():
    """Dynamic programming against every connected top-to-bottom path of a small error grid."""
    import itertools

    rng = np.random.default_rng(4)
    error = rng.uniform(size=(6, 4))
    best = min((sum(error[r, c] for r, c in enumerate(path)), path)
               for path in itertools.product(range(4), repeat=6)
               if all(abs(a - b) <= 1 for a, b in zip(path, path[1:])))
    path = min_cut_path(error)
    assert all(abs(a - b) <= 1 for a, b in zip(path, path[1:]))
    assert error[np.arange(6), path].sum() == pytest.approx(best[0])


def _painted_road(period_x: float, period_y: float) -> np.ndarray:
    """The road seen through the survey rig at W x H, painted with two sinusoids (grey, low
    contrast: no pixel reads as lane paint)."""
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    xy, ok = SURVEY.backproject(uu.ravel(), vv.ravel(), W, H)
    xy = np.nan_to_num(xy).reshape(H, W, 2)
    g = 0.45 + 0.08 * np.sin(2 * np.pi * xy[..., 0] / period_x) + 0.08 * np.sin(2 * np.pi * xy[..., 1] / period_y)
    g = np.where(ok.reshape(H, W), g, 0.45)
    return np.repeat((g * 200)[..., None], 3, axis=2).astype(np.uint8)


def test_back_projection_scale_and_orientation(tmp_path):
    period_x, period_y = 0.25, 0.40                          # metres along travel, across
    img = save_pair(tmp_path, "painted", _painted_road(period_x, period_y), np.ones((H, W), np.uint8))
    rec = PhotoSurfaces()
    res = rec.run({**BR, "images": [img], "labels": tmp_path / "labels"},
                  PhotoSurfacesParams(count=1, size=512, road_albedo=0.0, quilt=False))
    s = res.surfaces[0]
    lum = s.tile.astype(float).mean(axis=2)
    spectrum = np.abs(np.fft.rfft2(lum - lum.mean()))
    cycles_along_columns = ST_TILE_M / period_x              # per repeat: 16 (s runs along travel)
    cycles_along_rows = ST_TILE_M / period_y                 # 10
    row_peak = np.unravel_index(np.argmax(spectrum[0:1, 1:]), spectrum[0:1, 1:].shape)[1] + 1
    col_peak = np.argmax(spectrum[1:spectrum.shape[0] // 2, 0]) + 1
    assert row_peak == cycles_along_columns and col_peak == cycles_along_rows, (row_peak, col_peak)
    assert s.record["texel_m"] == pytest.approx(ST_TILE_M / 512)


def _layout(tmp_path: Path) -> Path:
    layout = write_lane_layout(tmp_path / "road.usda", 2, 3)
    return layout


def test_compose_offers_photo_surfaces_as_road_variants(real_materials, tmp_path):
    name = json.loads((real_materials / "materials.json").read_text())["materials"][0]["name"]
    done = compose(_layout(tmp_path), tmp_path / "town", preview=False, executor="serial",
                   road_textures=real_materials, road_material=name)
    assert not [f for f in validate_stage(done.town) if f.severity == "Error"]
    stage = Usd.Stage.Open(str(done.town))
    vset = stage.GetPrimAtPath("/Town").GetVariantSets().GetVariantSet("roadMaterial")
    assert {"asphalt", "cobblestone", "cement", name} <= set(vset.GetVariantNames())
    assert vset.GetVariantSelection() == name
    lane = stage.GetPrimAtPath("/Town/Roads/lane") or next(p for p in stage.Traverse() if p.GetName() == "lane")
    bound = UsdShade.MaterialBindingAPI(lane).ComputeBoundMaterial()[0]
    assert bound.GetPath().name == name
    files = [UsdShade.Shader(c).GetInput("file").Get().path for c in bound.GetPrim().GetChildren()
             if UsdShade.Shader(c).GetInput("file")]
    assert files and all((done.town.parent / "layers" / f).resolve().is_file() for f in files)
    vset.SetVariantSelection("asphalt")                      # the procedural look is one switch away
    assert UsdShade.MaterialBindingAPI(lane).ComputeBoundMaterial()[0].GetPath().name == "asphalt_worn"


def test_bad_inputs_are_one_line(tmp_path):
    lonely = tmp_path / "lonely"
    lonely.mkdir()
    (tmp_path / "nolabels").mkdir()
    cv2.imwrite(str(lonely / "a.png"), np.zeros((H, W, 3), np.uint8))
    one_line(run_cli("reconstruct", "photo-surfaces", lonely / "a.png", "--labels", tmp_path / "nolabels",
                     "-o", tmp_path / "m1"), "a.png", "no label")
    bare = save_pair(tmp_path / "bare", "bare", np.full((H, W, 3), 110, np.uint8), np.zeros((H, W), np.uint8))
    one_line(run_cli("reconstruct", "photo-surfaces", bare, "--labels", tmp_path / "bare/labels",
                     "-o", tmp_path / "m2"), "bare.png", "no clean road area")
    assert not (tmp_path / "m1").exists() and not (tmp_path / "m2").exists()


def test_bad_compose_options_fail_before_any_work(tmp_path, real_materials):
    layout = _layout(tmp_path)
    with pytest.raises(RoadtwinError, match="--road-material: no roadMaterial variant 'nosuch'"):
        compose(layout, tmp_path / "t1", preview=False, executor="serial", road_textures=real_materials,
                road_material="nosuch")
    (tmp_path / "empty").mkdir()
    with pytest.raises(RoadtwinError, match="materials.json"):
        compose(layout, tmp_path / "t2", preview=False, executor="serial", road_textures=tmp_path / "empty")
    assert not (tmp_path / "t1").exists() and not (tmp_path / "t2").exists()


def test_same_frames_same_bytes(real_materials, tmp_path):
    rec = PhotoSurfaces()
    result = rec.run({**BR, "images": [FRAME], "labels": TINY / "labels"}, PhotoSurfacesParams(count=1, **FAST))
    rec.write(result, tmp_path / "again")
    files = sorted(p.name for p in real_materials.iterdir())
    assert files == sorted(p.name for p in (tmp_path / "again").iterdir())
    assert all((real_materials / f).read_bytes() == (tmp_path / "again" / f).read_bytes() for f in files)
