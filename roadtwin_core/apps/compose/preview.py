"""``preview.png`` of a composed town: what a person wants to see first.

Left, one perspective render by the project's renderer (the ``warp`` renderer plugin, found
through the plugin manager, warp's own ray caster: for one 800 x 480 frame it beats loading
open3d) from a camera 2 m above a driving lane, looking along it at the lane spot with the
most defects 5-20 m ahead (markings come into view with the lane); right, the top-down map
(roads shaded by elevation, defects red, markings white), rasterized in numpy (pixel-centre
tests, vectorized over the triangles). The sheet is drawn with Pillow: matplotlib's import
and figure saving cost ~1.5 s of a preview that should take well under one. Given a stage path
alone, both are read back from the written stage, looks included. The composer instead passes
the town it holds in memory (:class:`~roadtwin_core.apps.compose.preview_scene.PreviewTown`): the same
triangles, labels and st through the writer's own functions, the materials parsed from the
stage's looks layer (textures at the MIP level the frame needs), and only the road the camera
can see (its horizontal wedge, within 150 m) in the ray-casting scene (reading Town01 back cost
~6 s). Without a usable renderer (warp not installed, plugin not loaded) the map stands alone
with a note saying why.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ...errors import RoadtwinError
from ...plugins import get_plugin_manager
from ...render import (Camera, GroundSampler, Intrinsics, RenderParams, build_render_mesh, look_from, stage_lanes,
                       to_srgb8)
from ...render.cameras import vehicle_height
from ...render.scene import MARKING_CLASS
from ...usd.town_reader import load_town

AHEAD_M = (5.0, 20.0)       # defects counted this far ahead of the camera ...
LATERAL_M = 6.0             # ... and at most this far to either side of the lane's line
CAMERA_HEIGHT_M = 2.0
RENDER_SIZE = (800, 480)
RENDER_HFOV_DEG = 75.0


@dataclass
class PreviewSpot:
    """The chosen camera: position (x, y), heading (rad), and how many defects it faces."""

    xy: np.ndarray
    heading: float
    defects_ahead: int
    lane: str


def choose_spot(lanes, defect_xy: np.ndarray, step_m: float = 1.0) -> PreviewSpot | None:
    """The lane point (every ``step_m`` along every lane, travel direction) with the most
    defect centres 5-20 m ahead and within ``LATERAL_M`` of the line of sight; among equals the
    one whose defects are nearest mid-window on average, then the first (deterministic); None
    without lanes."""
    best, best_score = None, -np.inf
    all_pts = np.asarray(defect_xy, dtype=np.float64).reshape(-1, 2)
    reach = math.hypot(AHEAD_M[1], LATERAL_M)        # no defect farther than this from its spot counts
    for lane in lanes:
        if lane.length <= 0:
            continue
        s = np.arange(0.0, lane.length + 1e-9, step_m)
        xy = lane.at(s)
        hd = lane.heading(s)
        # only the defects near this lane's box (same counts, a fraction of the pairs)
        lo, hi = xy.min(axis=0) - reach, xy.max(axis=0) + reach
        pts = all_pts[((all_pts >= lo) & (all_pts <= hi)).all(axis=1)]
        if len(pts):
            d = pts[None, :, :] - xy[:, None, :]
            c, sn = np.cos(hd)[:, None], np.sin(hd)[:, None]
            ahead = d[..., 0] * c + d[..., 1] * sn
            side = -d[..., 0] * sn + d[..., 1] * c
            seen = (ahead >= AHEAD_M[0]) & (ahead <= AHEAD_M[1]) & (np.abs(side) <= LATERAL_M)
            count = seen.sum(axis=1)
            mean_ahead = np.where(seen, ahead, 0.0).sum(axis=1) / np.maximum(count, 1)
        else:
            count = np.zeros(len(s), dtype=int)
            mean_ahead = np.zeros(len(s))
        # most defects; among equals, the one whose defects sit mid-window (best framed)
        score = count - 1e-3 * np.abs(mean_ahead - 0.5 * sum(AHEAD_M))
        k = int(np.argmax(score))
        if best is None or score[k] > best_score:
            best, best_score = PreviewSpot(xy[k], float(hd[k]), int(count[k]), lane.id), float(score[k])
    return best


BAND_COLOURS = (0.25, 0.85)   # the part of matplotlib's "terrain" map the elevation bands use
# matplotlib's "terrain" colour map (its segment data), so the map needs no matplotlib import (~1 s)
_TERRAIN = np.array([[0.00, 0.2, 0.2, 0.6], [0.15, 0.0, 0.6, 1.0], [0.25, 0.0, 0.8, 0.4],
                     [0.50, 1.0, 1.0, 0.6], [0.75, 0.5, 0.36, 0.33], [1.00, 1.0, 1.0, 1.0]])


def band_colours(n: int = 64) -> np.ndarray:
    """(n, 3) RGB in [0, 1]: the elevation bands, low to high."""
    x = np.linspace(*BAND_COLOURS, n)
    return np.stack([np.interp(x, _TERRAIN[:, 0], _TERRAIN[:, k]) for k in (1, 2, 3)], axis=1)


def fill_triangles(img: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, colours) -> None:
    """Paint triangles with corners ``a``, ``b``, ``c`` (each (N, 2) pixel coordinates, x right,
    y down; pixel (i, j) spans [i, i+1) x [j, j+1)) in colours (N, 3) or one colour (3,).
    Sub-pixel triangles, the bulk of a town's defect meshes, paint the pixel of their centroid;
    triangles whose bounding box holds up to 4 x 4 pixel centres are filled by testing those
    centres, all at once; the few larger ones one by one (same rule: a pixel is painted when its
    centre is inside). (Per-corner
    arrays, not (N, 3, 2) reductions: numpy reduces short axes slowly.)"""
    h, w = img.shape[:2]
    colours = np.broadcast_to(np.asarray(colours, np.uint8), (len(a), 3))
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    first = np.floor(lo - 0.5).astype(np.int32) + 1         # first pixel whose centre is >= lo
    span = np.floor(hi - 0.5).astype(np.int32) + 1 - first   # pixel centres inside the bbox
    size = np.maximum(span[:, 0], span[:, 1])
    cen = (a + b + c) / np.float32(3.0)
    cx = np.clip(cen[:, 0].astype(np.int32), 0, w - 1)
    cy = np.clip(cen[:, 1].astype(np.int32), 0, h - 1)
    tiny = size <= 1                                    # at most one pixel centre in the bbox
    img[cy[tiny], cx[tiny]] = colours[tiny]
    for k in (1, 2, 3, 4):
        sel = np.flatnonzero(size == k)
        if not len(sel):
            continue
        ox, oy = np.meshgrid(np.arange(k, dtype=np.int32), np.arange(k, dtype=np.int32))
        ix = first[sel, 0:1] + ox.ravel()[None]
        iy = first[sel, 1:2] + oy.ravel()[None]
        qx, qy = ix + np.float32(0.5), iy + np.float32(0.5)
        pa, pb, pc = a[sel], b[sel], c[sel]
        sgn = np.sign((pb[:, 0] - pa[:, 0]) * (pc[:, 1] - pa[:, 1]) - (pb[:, 1] - pa[:, 1]) * (pc[:, 0] - pa[:, 0]))
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        for p0, p1 in ((pa, pb), (pb, pc), (pc, pa)):
            inside &= ((p1[:, 0:1] - p0[:, 0:1]) * (qy - p0[:, 1:2])
                       - (p1[:, 1:2] - p0[:, 1:2]) * (qx - p0[:, 0:1])) * sgn[:, None] >= 0
        tri, _ = np.nonzero(inside)
        img[iy[inside], ix[inside]] = colours[sel][tri]
    for t in np.flatnonzero(size > 4):               # few: one small numpy test per triangle
        x0, y0 = max(first[t, 0], 0), max(first[t, 1], 0)
        x1, y1 = min(first[t, 0] + span[t, 0], w), min(first[t, 1] + span[t, 1], h)
        if x1 <= x0 or y1 <= y0:
            continue
        qx, qy = np.meshgrid(np.arange(x0, x1) + np.float32(0.5), np.arange(y0, y1) + np.float32(0.5))
        pa, pb, pc = a[t], b[t], c[t]
        sgn = np.sign((pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0]))
        inside = np.ones(qx.shape, bool)
        for p0, p1 in ((pa, pb), (pb, pc), (pc, pa)):
            inside &= ((p1[0] - p0[0]) * (qy - p0[1]) - (p1[1] - p0[1]) * (qx - p0[0])) * sgn >= 0
        img[y0:y1, x0:x1][inside] = colours[t]


def rasterize_map(mesh, width_px: int = 900, max_height_px: int | None = None) -> tuple[np.ndarray, tuple, tuple]:
    """Top-down RGB image (uint8, north up) of a RenderMesh: road faces coloured by mean
    elevation in 64 bands, then defect faces red, then lane markings white, on white;
    ``width_px`` wide, or less where ``max_height_px`` would be exceeded (same scale both ways).
    Returns (image, extent (x0, x1, y0, y1) in m, elevation range (lo, hi))."""
    v = mesh.vertices
    lo, hi = v[:, :2].min(axis=0) - 1.0, v[:, :2].max(axis=0) + 1.0
    scale = width_px / max(hi[0] - lo[0], 1e-6)
    if max_height_px is not None and (hi[1] - lo[1]) * scale > max_height_px:
        scale = max_height_px / max(hi[1] - lo[1], 1e-6)
        width_px = max(1, int(math.ceil((hi[0] - lo[0]) * scale)))
        hi[0] = lo[0] + width_px / scale
    h_px = max(1, int(math.ceil((hi[1] - lo[1]) * scale)))
    img = np.full((h_px, width_px, 3), 255, np.uint8)
    vp = np.empty((len(v), 2), np.float32)
    vp[:, 0] = (v[:, 0] - lo[0]) * scale
    vp[:, 1] = (hi[1] - v[:, 1]) * scale
    vz = v[:, 2].astype(np.float32)
    marking = (mesh.face_class == mesh.classes.index(MARKING_CLASS) if MARKING_CLASS in mesh.classes
               else np.zeros(len(mesh.faces), bool))
    defect = mesh.face_instance > 0
    road = ~defect & ~marking
    f = mesh.faces[road]
    z = (vz[f[:, 0]] + vz[f[:, 1]] + vz[f[:, 2]]) / np.float32(3.0)
    zlo, zhi = (float(z.min()), float(z.max())) if len(f) else (0.0, 1.0)
    zhi = max(zhi, zlo + 1e-3)
    band = np.clip(((z - zlo) / (zhi - zlo) * 63).astype(np.int32), 0, 63)
    palette = np.round(band_colours(64) * 255).astype(np.uint8)
    for mask, colour in ((road, palette[band]), (defect, (200, 20, 50)), (marking, (255, 255, 255))):
        f = mesh.faces[mask]
        fill_triangles(img, vp[f[:, 0]], vp[f[:, 1]], vp[f[:, 2]], colour)
    return img, (lo[0], hi[0], lo[1], hi[1]), (zlo, zhi)


def view_half_angle(cam, margin_deg: float = 10.0) -> float:
    """Half the horizontal angle (rad, about the camera's heading) that the image spans on the
    ground plane, plus a margin: the widest azimuth among the rays through the image border
    (a pitched camera's bottom corners spread wider than its horizontal field of view)."""
    k = cam.intrinsics
    u = np.r_[np.linspace(0, k.width, 9), np.full(9, k.width), np.linspace(0, k.width, 9), np.zeros(9)]
    v = np.r_[np.zeros(9), np.linspace(0, k.height, 9), np.full(9, k.height), np.linspace(0, k.height, 9)]
    d = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], axis=1) @ np.asarray(cam.rotation).T
    axis = np.asarray(cam.rotation)[:, 2]
    heading = math.atan2(axis[1], axis[0])
    az = np.arctan2(d[:, 1], d[:, 0]) - heading
    az = (az + np.pi) % (2 * np.pi) - np.pi
    return float(min(np.abs(az).max() + math.radians(margin_deg), np.pi))


def render_view(town_stage: Path, mesh, pm, lanes=None, view_mesh=None
                ) -> tuple[np.ndarray | None, str, PreviewSpot | None, object]:
    """(sRGB uint8 image or None, note, spot, camera) of the perspective view. ``lanes``
    (default: read from the stage) and ``view_mesh(spot, half_angle=) -> RenderMesh`` (default:
    ``mesh`` itself; ``half_angle``: :func:`view_half_angle`) let a caller that holds the town in
    memory skip reading the stage back and keep only what the camera can see."""
    try:
        renderer = pm.get("renderers", "warp")
    except RoadtwinError as exc:
        return None, f"no perspective view: {exc}", None, None
    if lanes is None:
        lanes = stage_lanes(town_stage)
    if not lanes:
        return None, "no perspective view: the town has no driving lane centrelines", None, None
    centres = []
    for inst in mesh.instances:
        pose = inst["attributes"].get("poseXYYaw")
        if pose is not None and len(pose) >= 2:
            centres.append(pose[:2])
    spot = choose_spot(lanes, np.asarray(centres, float).reshape(-1, 2))
    # the road under the camera only: a sampler over the whole town costs seconds and GBs on Town01
    v2 = mesh.vertices[:, :2]
    vnear = (np.abs(v2 - spot.xy) < 10.0).all(axis=1)
    f = mesh.faces
    near = vnear[f[:, 0]] & vnear[f[:, 1]] & vnear[f[:, 2]]
    ground = GroundSampler(SimpleNamespace(vertices=mesh.vertices, faces=mesh.faces[near]))
    z = vehicle_height(ground, spot.xy[None], np.array([spot.heading]))[0]
    if not np.isfinite(z):
        return None, f"no perspective view: no road under lane {spot.lane} at the chosen spot", spot, None
    # look down at the middle of the 5-20 m window
    pitch = -math.atan2(CAMERA_HEIGHT_M, 0.5 * sum(AHEAD_M)) + math.radians(4.0)
    pos = (spot.xy[0], spot.xy[1], z + CAMERA_HEIGHT_M)
    cam = Camera(Intrinsics.from_fov(*RENDER_SIZE, RENDER_HFOV_DEG), look_from(pos, spot.heading, pitch))
    try:
        scene = view_mesh(spot, half_angle=view_half_angle(cam)) if view_mesh is not None else mesh
        # warp's own BVH: for one small frame it beats open3d's Embree end to end (open3d's import
        # alone is ~1 s, and its scene ~170 MB more on Town01)
        frame = next(iter(renderer.render(scene, [cam], RenderParams(backend="warp"))))
    except ImportError as exc:                       # the plugin loaded but its engine (warp) did not
        return None, f"no perspective view: renderer warp unavailable ({exc})", spot, cam
    return to_srgb8(frame.rgb), "", spot, cam


def write_preview(path: Path, town_stage: Path, pm=None, title: str = "", dpi: int = 100, town=None) -> dict:
    """Write the preview PNG of the composed ``town_stage``; returns what it shows
    (``spot``, ``camera``, ``note`` when the perspective view is missing, timings).
    ``town``: the :class:`~roadtwin_core.apps.compose.preview_scene.PreviewTown` the composer just wrote
    (meshes in memory, materials read from the stage's looks layer), so nothing is read back.
    The PNG is composed with Pillow (no matplotlib: its import and figure saving took ~1.5 s);
    ``dpi`` is kept for callers and ignored."""
    t0 = time.perf_counter()
    pm = pm or get_plugin_manager()
    if town is not None:
        mesh = town.map_mesh()
        view, note, spot, cam = render_view(Path(town_stage), mesh, pm, town.lanes(), town.view_mesh)
    else:
        mesh = build_render_mesh(load_town(town_stage, looks=True))
        view, note, spot, cam = render_view(Path(town_stage), mesh, pm)
    t_render = time.perf_counter()
    img, extent, zrange = rasterize_map(mesh, width_px=MAP_SIZE[0], max_height_px=MAP_SIZE[1])
    del mesh
    t_map = time.perf_counter()
    view_title = (f"roadtwin warp render: lane {spot.lane}, {spot.defects_ahead} defects 5-20 m ahead"
                  if view is not None else "")
    sheet = compose_sheet(view, view_title, img, extent, zrange, spot, title or Path(town_stage).parent.name, note)
    sheet.save(path, format="PNG", compress_level=3)   # lossless; 6 took 2.3x as long for 11 % less
    return {"path": Path(path), "spot": spot, "camera": cam if view is not None else None, "note": note or None,
            "timings_s": {"render": t_render - t0, "map": t_map - t_render, "total": time.perf_counter() - t0}}


MAP_SIZE = (640, RENDER_SIZE[1])    # the map fits this box (pixels), beside the 800 x 480 view
_INK, _NOTE_INK = (20, 20, 20), (140, 0, 0)


@functools.lru_cache(maxsize=None)
def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:                                   # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def _nice_step(span: float) -> float:
    """A 1/2/5 x 10^k length near a fifth of ``span`` (the map's scale bar)."""
    raw = max(span / 5.0, 1e-9)
    k = 10 ** math.floor(math.log10(raw))
    return min((m * k for m in (1, 2, 5, 10)), key=lambda v: abs(v - raw))


def compose_sheet(view, view_title: str, img: np.ndarray, extent: tuple, zrange: tuple, spot, title: str,
                  note: str = ""):
    """The preview as one Pillow image: the view (if any) with its title, then the map with its
    title, the camera spot and heading (arrow), a scale bar and the elevation colour bar."""
    font, small = _font(14), _font(12)
    pad, head = 10, 26
    mh, mw = img.shape[:2]
    bar_w, bar_gap, label_w = 16, 12, 110
    vw = view.shape[1] + pad if view is not None else 0
    width = pad + vw + mw + bar_gap + bar_w + label_w
    height = head + max(mh, view.shape[0] if view is not None else 0) + 34
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    if view is not None:
        sheet.paste(Image.fromarray(np.ascontiguousarray(view)), (pad, head))
        draw.text((pad + view.shape[1] // 2, head // 2), view_title, fill=_INK, font=font, anchor="mm")
    mx, my = pad + vw, head
    sheet.paste(Image.fromarray(img), (mx, my))
    draw.rectangle((mx - 1, my - 1, mx + mw, my + mh), outline=(120, 120, 120))
    draw.text((mx + mw // 2, head // 2), title, fill=_INK, font=font, anchor="mm")
    x0, x1, y0, y1 = extent
    scale = mw / (x1 - x0)

    def px(x, y):
        return mx + (x - x0) * scale, my + (y1 - y) * scale

    if spot is not None:
        sx, sy = px(*spot.xy)
        ex, ey = px(spot.xy[0] + 25 * math.cos(spot.heading), spot.xy[1] + 25 * math.sin(spot.heading))
        draw.ellipse((sx - 4, sy - 4, sx + 4, sy + 4), fill=(0, 0, 0))
        draw.line((sx, sy, ex, ey), fill=(0, 0, 0), width=2)
        a = math.atan2(ey - sy, ex - sx)
        draw.polygon([(ex, ey)] + [(ex - 9 * math.cos(a + s), ey - 9 * math.sin(a + s)) for s in (0.45, -0.45)],
                     fill=(0, 0, 0))
    step = _nice_step(x1 - x0)                          # scale bar under the map
    bx, by = mx, my + mh + 12
    draw.line((bx, by, bx + step * scale, by), fill=_INK, width=3)
    draw.text((bx + step * scale + 6, by), f"{step:g} m   (x {x0:.0f}..{x1:.0f} m, y {y0:.0f}..{y1:.0f} m)",
              fill=_INK, font=small, anchor="lm")
    cx, cy0, ch = mx + mw + bar_gap, my + mh // 6, mh * 2 // 3     # elevation colour bar, high on top
    ramp = np.round(band_colours(64)[::-1] * 255).astype(np.uint8)
    bar = np.repeat(ramp[np.minimum((np.arange(ch) * 64) // max(ch, 1), 63)][:, None], bar_w, axis=1)
    sheet.paste(Image.fromarray(np.ascontiguousarray(bar)), (cx, cy0))
    draw.rectangle((cx - 1, cy0 - 1, cx + bar_w, cy0 + ch), outline=(120, 120, 120))
    zlo, zhi = zrange
    for z, y in ((zhi, cy0), (zlo, cy0 + ch)):
        draw.text((cx + bar_w + 5, y), f"{z:.3g} m", fill=_INK, font=small, anchor="lm")
    draw.text((cx + bar_w + 5, cy0 + ch // 2), "road\nelevation", fill=_INK, font=small, anchor="lm")
    draw.text((cx, cy0 + ch + 16), "defects", fill=(200, 20, 50), font=small, anchor="lm")
    if note:
        draw.text((pad, height - 6), note, fill=_NOTE_INK, font=small, anchor="ld")
    return sheet
