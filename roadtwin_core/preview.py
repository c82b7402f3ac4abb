"""``preview.png`` of a composed town: what a person wants to see first.

Left, one perspective render by the project's renderer (the ``warp`` renderer plugin, found
through the plugin manager) from a camera 2 m above a driving lane, looking along it at the
lane spot with the most defects 5-20 m ahead (markings come into view with the lane); right,
the top-down map (roads shaded by elevation, defects red, markings white), rasterized in numpy
(pixel-centre tests, vectorized over the triangles; not one matplotlib artist per triangle: well
under a second for a 1,000-defect town on an idle core). Given a stage path alone, both are read
back from the written stage, looks included. The composer instead passes the town it holds in
memory (:class:`~roadtwin_core.preview_scene.PreviewTown`): the same triangles, labels and st
through the writer's own functions, the materials parsed from the stage's looks layer, and only
the road within 150 m of the camera in the ray-casting scene (reading Town01 back cost ~6 s).
Without a usable renderer (warp not installed, plugin not loaded) the map stands alone with a
note saying why.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .errors import RoadtwinError

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
    pts = np.asarray(defect_xy, dtype=np.float64).reshape(-1, 2)
    for lane in lanes:
        if lane.length <= 0:
            continue
        s = np.arange(0.0, lane.length + 1e-9, step_m)
        xy = lane.at(s)
        hd = lane.heading(s)
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


def band_colormap(n: int = 64):
    from matplotlib import colormaps
    from matplotlib.colors import ListedColormap

    return ListedColormap(colormaps["terrain"](np.linspace(*BAND_COLOURS, n))[:, :3])


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


def rasterize_map(mesh, width_px: int = 900) -> tuple[np.ndarray, tuple, tuple]:
    """Top-down RGB image (uint8, north up) of a RenderMesh: road faces coloured by mean
    elevation in 64 bands, then defect faces red, then lane markings white, on white. Returns
    (image, extent (x0, x1, y0, y1) in m, elevation range (lo, hi))."""
    from .render.scene import MARKING_CLASS

    v = mesh.vertices
    lo, hi = v[:, :2].min(axis=0) - 1.0, v[:, :2].max(axis=0) + 1.0
    scale = width_px / max(hi[0] - lo[0], 1e-6)
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
    palette = (band_colormap(64).colors * 255).astype(np.uint8)
    for mask, colour in ((road, palette[band]), (defect, (200, 20, 50)), (marking, (255, 255, 255))):
        f = mesh.faces[mask]
        fill_triangles(img, vp[f[:, 0]], vp[f[:, 1]], vp[f[:, 2]], colour)
    return img, (lo[0], hi[0], lo[1], hi[1]), (zlo, zhi)


def render_view(town_stage: Path, mesh, pm, lanes=None, view_mesh=None
                ) -> tuple[np.ndarray | None, str, PreviewSpot | None, object]:
    """(sRGB uint8 image or None, note, spot, camera) of the perspective view. ``lanes``
    (default: read from the stage) and ``view_mesh(spot) -> RenderMesh`` (default: ``mesh``
    itself) let a caller that holds the town in memory skip reading the stage back."""
    from .render import Camera, GroundSampler, Intrinsics, RenderParams, look_from, stage_lanes, to_srgb8
    from .render.cameras import vehicle_height

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
        scene = view_mesh(spot) if view_mesh is not None else mesh
        frame = next(iter(renderer.render(scene, [cam], RenderParams())))
    except ImportError as exc:                       # the plugin loaded but its engine (warp) did not
        return None, f"no perspective view: renderer warp unavailable ({exc})", spot, cam
    return to_srgb8(frame.rgb), "", spot, cam


def write_preview(path: Path, town_stage: Path, pm=None, title: str = "", dpi: int = 100, town=None) -> dict:
    """Write the preview PNG of the composed ``town_stage``; returns what it shows
    (``spot``, ``camera``, ``note`` when the perspective view is missing, timings).
    ``town``: the :class:`~roadtwin_core.preview_scene.PreviewTown` the composer just wrote
    (meshes in memory, materials read from the stage's looks layer), so nothing is read back."""
    import time

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    from .plugins import get_plugin_manager
    from .render import build_render_mesh
    from .usd.town_reader import load_town

    t0 = time.perf_counter()
    pm = pm or get_plugin_manager()
    if town is not None:
        mesh = town.map_mesh()
        view, note, spot, cam = render_view(Path(town_stage), mesh, pm, town.lanes(), town.view_mesh)
    else:
        mesh = build_render_mesh(load_town(town_stage, looks=True))
        view, note, spot, cam = render_view(Path(town_stage), mesh, pm)
    t_render = time.perf_counter()
    img, extent, (zlo, zhi) = rasterize_map(mesh)
    t_map = time.perf_counter()

    if view is not None:
        fig, axes = plt.subplots(1, 2, figsize=(16, 6.2), gridspec_kw={"width_ratios": [1.25, 1]})
        ax_view, ax = axes
        ax_view.imshow(view)
        ax_view.set_axis_off()
        ax_view.set_title(f"roadtwin warp render: lane {spot.lane}, {spot.defects_ahead} defects 5-20 m ahead",
                          fontsize=10)
    else:
        fig, ax = plt.subplots(1, 1, figsize=(9, 7))
    ax.imshow(img, extent=extent, interpolation="antialiased")
    if spot is not None:
        c, s = math.cos(spot.heading), math.sin(spot.heading)
        ax.plot([spot.xy[0]], [spot.xy[1]], "o", color="k", ms=5)
        ax.annotate("", xy=(spot.xy[0] + 25 * c, spot.xy[1] + 25 * s), xytext=tuple(spot.xy),
                    arrowprops={"arrowstyle": "->", "color": "k", "lw": 1.5})
    sm = plt.cm.ScalarMappable(norm=Normalize(zlo, zhi), cmap=band_colormap(64))
    fig.colorbar(sm, ax=ax, label="road elevation (m)", shrink=0.7)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or Path(town_stage).parent.name, fontsize=10)
    if note:
        ax.text(0.01, 0.01, note, transform=ax.transAxes, fontsize=8, color="darkred", va="bottom",
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return {"path": Path(path), "spot": spot, "camera": cam if view is not None else None, "note": note or None,
            "timings_s": {"render": t_render - t0, "map": t_map - t_render, "total": time.perf_counter() - t0}}
