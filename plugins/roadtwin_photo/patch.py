"""One labelled defect instance of a photo -> footprint, textures and a 2.5D mesh (core-free:
numpy, OpenCV, scipy, shapely, triangle).

1. **Rectify**: an ortho grid (``texel_m``) around the instance's road footprint plus a band
   ``fade_m`` wide; the photo and the instance mask are sampled through the rig's homography
   (colour bilinear, mask bilinear then >= 0.5). The footprint is that ortho mask; its area is
   the instance's area on the road.
2. **Mesh outline**: the footprint grown by ``fade_m`` (the band where the texture fades into
   the road), its outer contour (holes filled, the largest part kept), simplified to half a texel
   and resampled every ``edge_m``; a constrained Delaunay triangulation inside (no Steiner points
   on the outline, so vertices 0..n-1 are the boundary loop at z = 0). A crack's outline is its
   strokes themselves (``crack_strokes``, :mod:`.strokes`: parts bridged, holes slit open), so
   the rendered label, which covers the whole mesh, is as thin as the photo's label strokes; its
   textures are edge-padded (every texel outside the strokes takes the nearest stroke texel's
   value, alpha 1: ``pad_from_footprint``) so the renderer's MIP levels keep the strokes' colour,
   and the albedo is their dark core's (``stroke_core``: the label is wider than the crack).
3. **Relief** by type (a prior, not a measurement: a single photo has no depth):
   ``pothole``: depth ``D = clip(depth_ratio * r_eq, min_depth_m, max_depth_m)`` (``r_eq`` the
   footprint's equivalent radius); the wall falls from the label edge over ``wall_ratio * r_eq``
   (smoothstep of the distance inside the label) and is *ravelled*: seeded band-limited noise of
   relative amplitude ``ravel`` on the wall (strongest mid-wall) plus a floor roughness, never
   above the road; outside the label (the fade band) z = 0.
   A pothole label that is a *strip along travel* (``strip_elongation`` x longer than wide, its
   long axis within ``strip_angle_deg`` of the direction of travel: the ravelled or patched
   wheel paths some surveys label pothole, as road_defects_br's RS_290 does) lost its surface
   course, not a bowl: its depth and wall scale with its half-width, capped at
   ``strip_max_depth_m`` (the 1-3 cm of the ``ravelling`` defect type), not with the radius of
   a disc of its area (a 6 m x 0.8 m strip would otherwise be a 10 cm trench).
   ``depression``: the same with half the depth and no ravelling. Every other type (crack,
   patch, ...) stays flush (z = 0); its relief lives in the normal map.
4. **Textures** (top view, travel upwards): albedo RGBA (alpha 1 on the label, falling linearly
   to 0 across the fade band; the colour itself fades there too, from the photo to the median
   road colour around the label, with paint dimmed: ``fade_into_road``), roughness (asphalt
   base, rougher where the photo has more local contrast, plus ``roughness_defect`` inside the
   label), normal (a height field from the photo's high-pass luminance, darker = lower,
   strengthened inside crack labels so the dark strokes read as grooves; tangent space with s
   to the right and t up the texture).
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np
import triangle
from scipy.ndimage import map_coordinates
from shapely.geometry import Polygon

from .rectify import OrthoGrid, PhotoRig, grid_around, rectify
from .seamless import REC709, linear_to_srgb8, srgb_to_linear
from .strokes import ccw_ring, min_face_area, pad_from_footprint, stroke_core, stroke_outline

DEEP_TYPES = {"pothole": 1.0, "depression": 0.5}
RAVELLED = {"pothole"}
GROOVED = {"crack"}


@dataclass
class PatchParams:
    texel_m: float = 0.01
    fade_m: float = 0.04
    edge_m: float = 0.04
    max_texels: int = 2048
    depth_ratio: float = 0.25
    min_depth_m: float = 0.02
    max_depth_m: float = 0.10
    wall_ratio: float = 0.35
    ravel: float = 0.35
    roughness_base: float = 0.8
    roughness_defect: float = 0.1
    normal_strength: float = 1.0
    road_albedo: float = 0.12     # linear luminance the road around the defect is scaled to (0: keep the photo's)
    crack_strokes: bool = True    # a crack's mesh (and so its label) = its strokes (strokes.py); False: the area
    stroke_gap_m: float = 0.01    # width of the bridges between strokes and of the slits opening holes
    strip_elongation: float = 3.0  # a pothole this many times longer than wide, along travel, is a strip (0: never)
    strip_angle_deg: float = 30.0  # the strip's long axis at most this far from the direction of travel
    strip_max_depth_m: float = 0.03
    stroke_core_px: int = 1       # crack strokes' colour: their darkest texel within this radius (0: the label's own)


@dataclass
class Patch:
    grid: OrthoGrid
    albedo: np.ndarray          # (R, C, 4) uint8 RGBA
    roughness: np.ndarray       # (R, C) uint8
    normal: np.ndarray          # (R, C, 3) uint8
    footprint: np.ndarray       # (R, C) bool: the label on the road
    area_m2: float              # footprint area on the road
    centroid: np.ndarray        # (2,) road xy of the footprint centroid (the asset's origin)
    vertices: np.ndarray        # (N, 3) local frame (x forward, y left, z up; origin = centroid)
    faces: np.ndarray
    boundary: np.ndarray        # indices 0..n-1
    st: np.ndarray              # (N, 2) texture coordinates of the vertices
    depth_m: float              # the prior depth used (0 = flush)
    relief: str = "flush"       # "bowl", "strip" (a pothole label along travel: surface course lost) or "flush"


def footprint_shape(xy: np.ndarray) -> tuple[float, float, float]:
    """Length and width (m) of a footprint's points along their principal axes, and the long
    axis's angle to the direction of travel (+x), in degrees, 0-90."""
    c = xy - xy.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov(c.T))
    major, minor = vecs[:, 1], vecs[:, 0]
    length, width = float(np.ptp(c @ major)), float(np.ptp(c @ minor))
    angle = math.degrees(math.atan2(abs(major[1]), abs(major[0])))
    return length, width, angle


def _smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _noise(shape_xy: np.ndarray, scale_m: float, rng: np.random.Generator) -> Callable[[np.ndarray], np.ndarray]:
    """Seeded band-limited noise in [-1, 1] over the road: random values on a lattice of
    ``scale_m`` through an interpolating cubic spline (a function of road xy)."""
    lo, hi = shape_xy.min(axis=0) - scale_m, shape_xy.max(axis=0) + scale_m
    nx = max(4, int(math.ceil((hi[0] - lo[0]) / scale_m)) + 1)
    ny = max(4, int(math.ceil((hi[1] - lo[1]) / scale_m)) + 1)
    vals = rng.uniform(-1, 1, (nx, ny))

    def at(xy: np.ndarray) -> np.ndarray:
        idx = np.stack([(xy[:, 0] - lo[0]) / (hi[0] - lo[0]) * (nx - 1), (xy[:, 1] - lo[1]) / (hi[1] - lo[1]) * (ny - 1)])
        return np.clip(map_coordinates(vals, idx, order=3, mode="nearest"), -1.0, 1.0)

    return at


def instance_seed(source: str, instance: int) -> int:
    return zlib.crc32(f"{source}#{instance}".encode())


def to_road_albedo(colour: np.ndarray, ring: np.ndarray, target: float) -> np.ndarray:
    """The photo's colour as an albedo: a photo holds light x albedo x exposure, so the patch is
    scaled (in linear light) until the road around the defect (``ring``) has the luminance of
    the town's asphalt. The defect keeps its contrast to its own road, and sits in the town's
    road without a bright or dark halo whatever the photo's exposure was."""
    lin = srgb_to_linear(colour)
    lum = lin @ REC709
    ref = float(np.median(lum[ring] if ring.any() else lum))
    return linear_to_srgb8(lin * (target / max(ref, 1e-4)))


def fade_into_road(colour: np.ndarray, foot: np.ndarray, alpha: np.ndarray, ring: np.ndarray,
                   bright_max: float = 1.5) -> np.ndarray:
    """The fade band baked into the colour: outside the label each texel goes, in linear light,
    from the photo (alpha 1) to the median colour of the road ring (alpha 0). A renderer draws
    the decal opaque (its mesh replaces the road surface, there is nothing under it to blend
    with), so without this the band shows whatever the photo had beside the label: lane paint
    right next to a pothole became a white rim in the town. Before the blend, band texels
    brighter than ``bright_max`` x the ring's median luminance are dimmed to it (paint, glare;
    dark texels stay: a hole's dark edge often spills past a hand-drawn label)."""
    lin = srgb_to_linear(colour)
    lum = lin @ REC709
    sel = ring if ring.any() else ~foot
    if not sel.any():
        return colour
    road = np.median(lin[sel], axis=0)
    cap = bright_max * float(road @ REC709)
    band = ~foot
    dim = np.where(band & (lum > cap), cap / np.maximum(lum, 1e-9), 1.0)
    lin = lin * dim[..., None]
    a = np.where(band, alpha, 1.0)[..., None]
    return linear_to_srgb8(a * lin + (1.0 - a) * road)


def outline(mask: np.ndarray, grid: OrthoGrid, edge_m: float):
    """Outer outline of a texel mask as a simple road polygon (shapely), holes filled, the
    largest part kept; None when nothing usable is left."""
    import cv2

    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    best = None
    for c in contours:
        c = c[:, 0, :].astype(float)                   # (col, row)
        if len(c) < 3:
            continue
        xy = grid.to_xy(np.column_stack([c[:, 1], c[:, 0]]))
        poly = Polygon(xy)
        if not poly.is_valid:
            poly = poly.buffer(0)
        if poly.geom_type == "MultiPolygon":
            poly = max(poly.geoms, key=lambda g: g.area)
        if best is None or poly.area > best.area:
            best = poly
    if best is None or best.area <= 0:
        return None
    # the contour runs through boundary texel centres: grow by half a texel to the texel edges
    poly = best.buffer(grid.texel / 2, join_style=2).simplify(grid.texel / 2, preserve_topology=True)
    if poly.geom_type == "MultiPolygon":
        poly = max(poly.geoms, key=lambda g: g.area)
    return poly


def resample_ring(poly, step: float) -> np.ndarray:
    ring = np.asarray(poly.exterior.coords)[:-1]
    closed = np.vstack([ring, ring[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    out = []
    for p, q, L in zip(closed[:-1], closed[1:], seg):
        k = max(1, int(math.ceil(L / step)))
        out.append(p + (q - p) * (np.arange(k)[:, None] / k))
    pts = np.vstack(out)
    # drop near-duplicates (simplify can leave very short edges)
    keep = np.r_[True, np.linalg.norm(np.diff(pts, axis=0), axis=1) > step * 0.05]
    pts = pts[keep]
    if np.linalg.norm(pts[0] - pts[-1]) <= step * 0.05:
        pts = pts[:-1]
    # counter-clockwise
    a = 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    return pts if a > 0 else pts[::-1].copy()


def make_patch(image: np.ndarray, mask: np.ndarray, rig: PhotoRig, defect_type: str, p: PatchParams,
               seed: int) -> Patch | None:
    """``image`` (H, W, 3) uint8 RGB, ``mask`` (H, W) bool of one instance -> a Patch (None when
    the footprint is too small to mesh at this texel size)."""
    import cv2

    h, w = mask.shape
    vs, us = np.nonzero(mask)
    # the footprint's road extent from its pixels' corners
    cu = np.concatenate([us - 0.5, us + 0.5, us - 0.5, us + 0.5])
    cv = np.concatenate([vs - 0.5, vs - 0.5, vs + 0.5, vs + 0.5])
    xy, ok = rig.backproject(cu, cv, w, h)
    xy = xy[ok]
    grid = grid_around(xy, p.texel_m, p.fade_m + 3 * p.texel_m, p.max_texels)
    colour = rectify(image, rig, grid)
    cover = rectify(mask.astype(np.float32), rig, grid)
    foot = cover >= 0.5
    if foot.sum() < 9:
        return None
    t = grid.texel
    area = float(foot.sum()) * t * t
    rr, cc = np.nonzero(foot)
    centroid = grid.to_xy(np.column_stack([rr.mean(), cc.mean()]))[0]

    # distances (m) inside and outside the label, on the texel grid
    inside = cv2.distanceTransform(foot.astype(np.uint8), cv2.DIST_L2, 5) * t
    outside = cv2.distanceTransform((~foot).astype(np.uint8), cv2.DIST_L2, 5) * t
    fade = p.fade_m
    alpha = np.where(foot, 1.0, np.clip(1.0 - outside / max(fade, 1e-9), 0.0, 1.0))

    # mesh outline: the footprint grown by the fade band; a crack's: its strokes (holes <= 3x3 texels filled)
    flat_strokes = defect_type in GROOVED and p.crack_strokes
    if flat_strokes:
        poly = stroke_outline(foot, grid, p.stroke_gap_m, (3 * t) ** 2)
        min_area = 9 * t * t
    else:
        poly = outline(outside <= fade, grid, p.edge_m)
        min_area = (3 * p.edge_m) ** 2 / 4
    if poly is None or poly.area < min_area:
        return None
    # a flat crack keeps its outline's vertices and gets no interior points: points added on its
    # edges leave slivers (near-180-degree corners), and quality refinement in strokes a texel or two
    # wide never ends
    loop = ccw_ring(poly) if flat_strokes else resample_ring(poly, p.edge_m)
    n = len(loop)
    seg = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
    try:
        tri = triangle.triangulate({"vertices": loop, "segments": seg},
                                   "pY" if flat_strokes else f"pq25a{p.edge_m ** 2 * 0.6:.10f}Y")
    except RuntimeError:                    # Triangle refuses the outline: no asset (skipped, counted)
        return None
    verts = tri["vertices"]
    faces = tri["triangles"]
    if not np.allclose(verts[:n], loop) or min_face_area(verts - verts.mean(axis=0), faces) <= 1e-9:
        return None

    # relief
    r_eq = math.sqrt(area / math.pi)
    z = np.zeros(len(verts))
    depth, relief = 0.0, "flush"
    if defect_type in DEEP_TYPES:
        depth = DEEP_TYPES[defect_type] * float(np.clip(p.depth_ratio * r_eq, p.min_depth_m, p.max_depth_m))
        relief = "bowl"
        if defect_type in RAVELLED and p.strip_elongation > 0:
            length, width, angle = footprint_shape(grid.to_xy(np.column_stack([rr, cc])))
            width += t                                      # texel centres -> the footprint's extent
            if length + t >= p.strip_elongation * width and angle <= p.strip_angle_deg:
                r_eq = width / 2                            # depth and wall from the half-width
                floor = min(p.min_depth_m / 2, p.strip_max_depth_m)   # 1-3 cm by default, as the ravelling type
                depth, relief = float(np.clip(p.depth_ratio * r_eq, floor, p.strip_max_depth_m)), "strip"
        rc = grid.to_rc(verts)
        d_in = cv2.remap(inside.astype(np.float32), rc[:, 1].astype(np.float32)[None], rc[:, 0].astype(np.float32)[None],
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)[0]
        wall = max(p.wall_ratio * r_eq, 2 * t)
        s = _smoothstep(d_in / wall)
        rng = np.random.default_rng(seed)
        if defect_type in RAVELLED and p.ravel > 0:
            n1 = _noise(verts, max(0.03, r_eq / 4), rng)(verts)
            n2 = _noise(verts, max(0.015, r_eq / 10), rng)(verts)
            s = np.clip(s + p.ravel * (0.7 * n1 + 0.3 * n2) * 4 * s * (1 - s), 0.0, 1.0)
            s = s * (1 + 0.08 * n2 * (s > 0.95))
        z = -depth * s
        z[d_in <= 0] = 0.0
    z[:n] = 0.0
    z = np.minimum(z, 0.0)
    verts3 = np.column_stack([verts - centroid, z])

    # textures
    ring = ~foot & (outside <= fade + 3 * t)
    if p.road_albedo > 0:
        colour = to_road_albedo(colour, ring, p.road_albedo)
    colour = fade_into_road(colour, foot, alpha, ring)
    lum = cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    sigma = max(1.0, 0.02 / t)
    high = lum - cv2.GaussianBlur(lum, (0, 0), sigma)
    local_std = np.sqrt(np.maximum(cv2.GaussianBlur(high * high, (0, 0), sigma), 0))
    ref = float(np.median(local_std)) + 1e-6
    rough = p.roughness_base + 0.1 * np.tanh(local_std / ref - 1) + p.roughness_defect * foot
    roughness = (np.clip(rough, 0.05, 1.0) * 255 + 0.5).astype(np.uint8)
    height = high.copy()
    if defect_type in GROOVED:
        dark = np.clip(-high, 0, None) * foot
        height -= 3.0 * dark
    height *= 0.015 * p.normal_strength / max(t, 1e-9)     # 1.5 cm per unit of luminance contrast, in texels
    gy, gx = np.gradient(height)                            # per texel along rows (down = -x), cols (right = -y)
    # tangent space: s to the right (+col), t up (-row)
    nx, ny = -gx, gy
    nrm = np.stack([nx, ny, np.ones_like(nx)], axis=-1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    normal = ((nrm * 0.5 + 0.5) * 255 + 0.5).astype(np.uint8)
    albedo = np.dstack([colour.astype(np.uint8), (alpha * 255 + 0.5).astype(np.uint8)])
    if flat_strokes:                # the mesh is the strokes: no texel beside them may bleed into them
        albedo = pad_from_footprint(albedo, stroke_core(lum, foot, p.stroke_core_px))
        roughness, normal = (pad_from_footprint(m, foot) for m in (roughness, normal))

    # texture coordinates: s = column / cols, t = 1 - row / rows (texel edges)
    rc = grid.to_rc(verts)
    st = np.column_stack([(rc[:, 1] + 0.5) / grid.cols, 1.0 - (rc[:, 0] + 0.5) / grid.rows])
    return Patch(grid, albedo, roughness, normal, foot, area, centroid, verts3, faces, np.arange(n), st, depth, relief)
