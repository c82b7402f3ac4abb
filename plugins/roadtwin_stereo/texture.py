"""Texture for stereo-made defects: the left image's pixels over each footprint, as an
orthographic patch in the defect's local XY (core-free: numpy, OpenCV, scipy, shapely).

The mesh of :mod:`.mesh` is measured: every vertex is a 3D point in the local road frame
(``origin`` + x e1 + y e2 + z n in camera coordinates). So each texel of a grid over the local XY
is lifted onto that surface (z interpolated from the mesh, 0 on the road around it), carried into
the camera and projected through K into the left image, where its colour is sampled
(bilinear). What the texture shows at (x, y) is what the camera saw at that surface point,
the pothole's walls and floor included (no perspective smear; parts the rim hides from the
camera get the rim's colour: no occlusion test). The grid is axis-aligned in local XY, so the
vertices' st is exactly affine in XY (``DefectLook.fit``), which is what a decal needs.

- alpha: 1 on the detected instance (texels whose image position lies in its mask), falling
  linearly to 0 at the mesh's outline (the detection padded by mesh.py): the patch fades into
  the road where the asset meets it;
- colour as an albedo: scaled in linear light until the road band around the instance has
  ``road_albedo``'s luminance, as the photo reconstructor does (a minimal copy of that rule:
  a plugin may not import another, and no public core helper holds it);
- :func:`disparity_from_transformed`: a raw disparity back from a normalised transformed map
  (Fan et al.'s ``disp_tg``) and a *nominal* rig, so those frames can be meshed at all;
  :func:`nominal_depth_scale` is the mark its models carry (``inputs["depth_scale"]``: the asset
  says ``roadtwin:depthScale = "nominal"`` with the numbers used, docs/architecture.md);
  :func:`nominal_inputs` gives both, and K, for one map through :data:`NOMINAL_RIG`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.interpolate import LinearNDInterpolator
from shapely import contains_xy
from shapely.geometry import Polygon

from .mesh import DefectInstance

LUMA = np.array([0.2126, 0.7152, 0.0722])      # Rec. 709 linear luminance
MIN_AUTO_TEXEL_M, MAX_AUTO_TEXEL_M = 0.001, 0.05  # bounds of the automatic texel (one image pixel at the defect)


@dataclass
class TextureSource:
    """What texturing needs of a frame: the left image (RGB, the disparity's pixels), K, where the
    frame came from and its license, and the patch settings."""

    rgb: np.ndarray
    K: np.ndarray
    frame: str
    license: str
    texel_m: float = 0.0           # m per texel; 0: the image's own resolution at the defect
    road_albedo: float = 0.12
    max_texels: int = 2048


@dataclass
class StereoPatch:
    albedo: np.ndarray          # (R, C, 4) uint8 sRGB + alpha, row 0 at the largest local y
    st: np.ndarray              # (N, 2) texture coordinates of the mesh vertices
    area_m2: float              # the detected instance's area on the road (alpha = 1 texels)
    texel_m: float


def license_for(image: Path) -> str:
    """The first line of a LICENSE file beside the frame or up to three folders above it."""
    for d in [image.parent, *list(image.parents)[1:4]]:
        for name in ("LICENSE", "LICENSE.txt", "LICENSE.md", "COPYING"):
            f = d / name
            if f.is_file():
                first = next((ln.strip() for ln in f.read_text(errors="replace").splitlines() if ln.strip()), "")
                return f"{first or 'license'} ({f})"
    return "unknown (no LICENSE file beside the frame)"


def texture_source(inputs: dict[str, Any], K: np.ndarray | None, shape: tuple[int, int], *, texel_m: float,
                   road_albedo: float) -> TextureSource | None:
    """The frame's texture source: ``inputs["rgb"]`` (the left colour image of a disparity map),
    else ``inputs["left"]`` (a pair's left image); None without an image or K. An image of
    another size than the disparity is an error naming it (ValueError)."""
    import cv2

    image = inputs.get("rgb") if inputs.get("rgb") is not None else inputs.get("left")
    if image is None or K is None:
        return None
    if isinstance(image, np.ndarray):
        rgb, frame = image, str(inputs.get("source") or "array")
        lic = str(inputs.get("license") or "unknown (array input)")
    else:
        path = Path(image)
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"{path}: cannot read the colour image")
        rgb, frame = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), str(path)
        lic = str(inputs.get("license") or license_for(path))
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=2)
    if rgb.shape[:2] != tuple(shape):
        raise ValueError(f"{frame}: colour image is {rgb.shape[1]}x{rgb.shape[0]} px, the disparity "
                         f"{shape[1]}x{shape[0]} px")
    return TextureSource(np.ascontiguousarray(rgb[..., :3], dtype=np.uint8), np.asarray(K, np.float64), frame, lic,
                         texel_m, road_albedo)


def to_road_albedo(colour: np.ndarray, road: np.ndarray, target: float) -> np.ndarray:
    """sRGB colour scaled in linear light until the median luminance of the ``road`` texels is
    ``target`` (a photo holds light x albedo x exposure; the town's asphalt is an albedo)."""
    c = colour.astype(np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)        # IEC 61966-2-1
    lum = lin @ LUMA
    ref = float(np.median(lum[road] if road.any() else lum))
    lin = np.clip(lin * (target / max(ref, 1e-4)), 0.0, 1.0)
    c = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055)
    return (c * 255 + 0.5).astype(np.uint8)


def _grid(xy: np.ndarray, texel: float, max_texels: int) -> tuple[np.ndarray, float, int, int]:
    """Lower-left corner, texel size, rows and columns of a grid covering ``xy`` plus a texel."""
    lo, hi = xy.min(axis=0) - texel, xy.max(axis=0) + texel
    texel = max(texel, float((hi - lo).max()) / max_texels)
    cols, rows = (int(np.ceil(e / texel)) for e in hi - lo)
    return lo, texel, rows, cols


def make_patch(src: TextureSource, inst: DefectInstance, mask: np.ndarray) -> StereoPatch | None:
    """One instance's patch: ``inst`` its mesh (local frame, camera pose), ``mask`` its detected
    pixels. None when no texel of the instance lands in the image."""
    import cv2

    verts, loop = inst.vertices, inst.boundary
    texel = src.texel_m or float(np.clip(inst.origin[2] / src.K[0, 0], MIN_AUTO_TEXEL_M, MAX_AUTO_TEXEL_M))
    lo, t, rows, cols = _grid(verts[:, :2], texel, src.max_texels)
    x = lo[0] + (np.arange(cols) + 0.5) * t
    y = lo[1] + (rows - np.arange(rows) - 0.5) * t                      # row 0 at the top (largest y)
    gx, gy = np.meshgrid(x, y)
    z = LinearNDInterpolator(verts[:, :2], verts[:, 2], fill_value=0.0)(gx, gy)
    cam = inst.to_camera(np.stack([gx, gy, z], axis=-1).reshape(-1, 3))
    K = src.K
    u = (K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 1] * cam[:, 1] / cam[:, 2] + K[0, 2]).reshape(rows, cols)
    v = (K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]).reshape(rows, cols)
    h, w = mask.shape
    seen = (cam[:, 2].reshape(rows, cols) > 0) & (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
    mu, mv = u.astype(np.float32), v.astype(np.float32)
    colour = cv2.remap(src.rgb, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    core = (cv2.remap(mask.astype(np.uint8), mu, mv, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0) > 0) & seen
    foot = contains_xy(Polygon(verts[loop, :2]), gx, gy) & seen
    if not core.any():
        return None
    d_out = cv2.distanceTransform((~core).astype(np.uint8), cv2.DIST_L2, 5)
    d_edge = cv2.distanceTransform(foot.astype(np.uint8), cv2.DIST_L2, 5)
    alpha = np.where(core, 1.0, np.where(foot, d_edge / np.maximum(d_edge + d_out, 1e-9), 0.0))
    if src.road_albedo > 0:
        colour = to_road_albedo(colour, foot & ~core, src.road_albedo)
    albedo = np.dstack([colour, (alpha * 255 + 0.5).astype(np.uint8)])
    st = np.column_stack([(verts[:, 0] - lo[0]) / (cols * t), (verts[:, 1] - lo[1]) / (rows * t)])
    return StereoPatch(albedo, st, float(core.sum()) * t * t, t)


def source_text(src: TextureSource, disparity: str, instance: int, pixels: int) -> str:
    """``roadtwin:source`` of a textured stereo asset: the frame (its colour image and, where
    another file, its disparity), the instance and the license."""
    also = "" if disparity in (src.frame, "array") else f", disparity {disparity}"
    return f"stereo frame {src.frame}{also} (pothole instance {instance}, {pixels} px); license: {src.license}"


def disparity_from_transformed(transformed: np.ndarray, K: np.ndarray, baseline_m: float, height_m: float,
                               pitch_down_deg: float, units_per_px: float) -> np.ndarray:
    """A raw disparity map (px, NaN invalid) from a transformed one ``d' = d - f(v') + delta``
    that was min-max normalised (Fan et al.'s ``disp_tg``: 0 = invalid, the road near one
    constant), given the rig it *should* have been taken with: the road disparity of a camera
    ``height_m`` above a flat road, pitched ``pitch_down_deg`` down, no roll
    (``d_road = -f B (n . ray) / H``), plus the map's deviation from its road value (the median)
    divided by ``units_per_px``, the map's units per disparity pixel. The relief is the map's;
    its scale is as good as these numbers (the normalisation threw the true ones away)."""
    d = np.asarray(transformed, np.float64).copy()
    d[~np.isfinite(d) | (d <= 0)] = np.nan
    road = float(np.nanmedian(d))
    h, w = d.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    p = np.radians(pitch_down_deg)
    n_dot_ray = -np.cos(p) * (v - K[1, 2]) / K[1, 1] - np.sin(p)      # n = (0, -cos p, -sin p): up, to the camera
    d_road = -K[0, 0] * baseline_m * n_dot_ray / height_m
    out = d_road + (d - road) / units_per_px
    out[(n_dot_ray >= 0) | ~(out > 0)] = np.nan
    return out


def nominal_depth_scale(K: np.ndarray, baseline_m: float, height_m: float, pitch_down_deg: float,
                        units_per_px: float) -> dict[str, Any]:
    """The mark of models meshed from :func:`disparity_from_transformed`'s map (give it as
    ``inputs["depth_scale"]``): their relief is measured but its metres rest on these assumed
    numbers, so each asset says ``roadtwin:depthScale = "nominal"`` and keeps them."""
    return {"kind": "nominal", "basis": "transformed disparity (min-max normalised) through an assumed rig",
            "fx_px": float(np.asarray(K, np.float64)[0, 0]), "baseline_m": float(baseline_m),
            "height_m": float(height_m), "pitch_down_deg": float(pitch_down_deg), "units_per_px": float(units_per_px)}


# Fan et al.'s stereo pothole frames through roadtwin's `inspection` rig preset (ZED-class 0.12 m
# baseline, 90 deg, 1.0 m up, 60 deg down; nominal) and 10,000 map units per disparity px (nominal:
# the normalised maps lost the true scale; this puts their potholes 3-7 cm deep).
NOMINAL_RIG = {"hfov_deg": 90.0, "baseline_m": 0.12, "height_m": 1.0, "pitch_down_deg": 60.0, "units_per_px": 10000.0}


def nominal_inputs(transformed: np.ndarray, rig: dict[str, float] = NOMINAL_RIG) -> dict[str, Any]:
    """A transformed (normalised) map as the reconstructor's metric inputs through a nominal rig:
    ``disparity`` (:func:`disparity_from_transformed`), ``K`` (pinhole, centred, ``hfov_deg``),
    ``baseline`` and the ``depth_scale`` mark its assets carry (:func:`nominal_depth_scale`)."""
    t = np.nan_to_num(np.asarray(transformed, np.float64))
    h, w = t.shape
    f = w / 2 / np.tan(np.radians(rig["hfov_deg"] / 2))
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    numbers = (rig["baseline_m"], rig["height_m"], rig["pitch_down_deg"], rig["units_per_px"])
    return {"disparity": disparity_from_transformed(t, K, *numbers), "K": K, "baseline": rig["baseline_m"],
            "depth_scale": nominal_depth_scale(K, *numbers)}


def check_depth_scale(mark: Any) -> dict[str, Any] | None:
    """``inputs["depth_scale"]`` checked: None, or a dict with a string ``kind`` and string or
    number values (what a USD customData holds). ValueError names what is wrong."""
    if mark is None:
        return None
    if not isinstance(mark, dict) or not isinstance(mark.get("kind"), str) or not mark["kind"]:
        raise ValueError(f"depth_scale input must be a dict with a string 'kind' (e.g. nominal_depth_scale(...)), "
                         f"got {mark!r}")
    bad = [k for k, v in mark.items() if not isinstance(k, str) or isinstance(v, bool)
           or not isinstance(v, (str, int, float)) or (isinstance(v, float) and not np.isfinite(v))]
    if bad:
        raise ValueError(f"depth_scale input: {bad[0]!r} must be a string or a finite number, got {mark[bad[0]]!r}")
    return dict(mark)
