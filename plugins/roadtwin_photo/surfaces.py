"""Road surfaces from photos: asphalt materials cut from the defect-free road of labelled frames.

Registers the reconstructor ``photo_surfaces`` (produces ``"materials"``), run by
``roadtwin reconstruct photo-surfaces IMAGES... --labels DIR --classmap builtin:road_defects_br
--rig survey -o MATERIALS``; ``roadtwin compose --road-textures MATERIALS`` offers what it writes
as ``roadMaterial`` variants beside the procedural ones.

1. Each frame's clean road (:mod:`.road_area`: road class, away from defects, paint, the image's
   edge, where a pixel covers at most ``max_gsd_m`` of road) on a ``search_texel_m`` grid, and
   the largest window of side ``ST_TILE_M / k`` (``k`` = 1, 2, 3 ...: the material must repeat
   every ``ST_TILE_M`` metres, the st convention of ``roadtwin_core.looks``) that fits there
   with its blend overlap, nearest the camera.
2. ``count`` windows from different frames: none in shade (lightness that varies over
   decimetres: the dappled shadow of a tree would repeat with the tile), the sharper half (the
   window's ground sample distance), the biggest windows first and, among them, colours and
   contrasts as different as can be (greedy farthest-point on CIELAB lightness, chroma and
   texture contrast): new black asphalt, grey worn asphalt, patches, stains.
3. Each window back-projected through the rig at the procedural asphalt's texel
   (``ST_TILE_M / size``), at one resolution all over (its coarsest photo sample along and
   across travel: a forward camera sees a window's near end sharper than its far end), turned
   so that the texture's s runs along travel and t to the left (lane-aligned st).
   A window smaller than ``ST_TILE_M`` (the usual case: about 2 m) is not repeated k x k, which
   would put its stains and wheel paths back every window, a band across the lane no real road
   has; with up to ``sources - 1`` windows of other frames that look like it (same kind of
   road) it is quilted into one whole tile (toroidal image quilting with minimum-error boundary
   cuts, :mod:`.quilting`, :mod:`.quilted`, :mod:`.surface_tiles`; its period correlation is
   recorded). ``quilt=false``, or a window of ``ST_TILE_M``, makes the one window seamless
   (:mod:`.seamless`) and repeats it ``k`` times a side. Seams are measured; roughness and
   normal maps are derived from the colour. A photo holds light x albedo x
   exposure: all surfaces are scaled in linear light by one factor that brings their median
   luminance to ``road_albedo`` (the town's asphalt), so lighter and darker ones stay so.

:meth:`PhotoSurfaces.write` writes ``<name>_diffuse.png``, ``<name>_roughness.png``,
``<name>_normal.png`` (the procedural set's files and sizes: normal at 1/2, roughness at 1/4)
and ``materials.json`` (``roadtwin:source``: the frames and their license; the windows on the
road, the ground sample distance, seam and period measures), replacing the folder atomically.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field as dc_field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from roadtwin_core import RoadtwinError, check_params, field
from roadtwin_core.atomic import atomic_output_dir
from roadtwin_core.usd import safe_prim_name

from .photo_io import frame_pairs, license_for, read_label, read_rgb, rig_from
from .quilted import same_road
from .rectify import PhotoRig
from .road_area import CleanParams, SearchView, clean_area, largest_square, search_view, square_at
from .seamless import encode_normal, linear_luminance
from .surface_tiles import ST_TILE_M, Surface, as_albedo, cut_surface, quilt_surface

MATERIALS_FILE = "materials.json"
SHADE_SCALE_M = 0.1


@dataclass
class PhotoSurfacesParams:
    count: int = field(6, lo=1, hi=64, doc="surfaces to cut, each from another frame")
    size: int = field(1024, lo=64, hi=4096, doc=f"texels per {ST_TILE_M:g} m repeat (the procedural asphalt's)")
    overlap: float = field(0.125, lo=0.02, hi=0.5, doc="blend band of the seamless wrap, a fraction of the window")
    min_window_m: float = field(1.0, lo=0.1, hi=ST_TILE_M, doc="smallest window side cut from a frame (m)")
    max_gsd_m: float = field(0.03, lo=0.002, hi=0.5, doc="road metres per photo pixel (worst direction) at most")
    defect_margin_m: float = field(0.25, lo=0.0, hi=5.0, doc="distance kept from labelled defects (m)")
    paint_margin_m: float = field(0.15, lo=0.0, hi=5.0, doc="distance kept from paint, non-asphalt and the "
                                  "road label's edge (m)")
    border_px: int = field(8, lo=0, hi=200, doc="photo pixels kept from the image's edge")
    paint_lightness: float = field(45.0, lo=1.0, hi=255.0, doc="8-bit L* above the road's median that is paint")
    max_chroma: float = field(22.0, lo=1.0, hi=255.0, doc="8-bit Lab chroma above which a pixel is not asphalt")
    search_texel_m: float = field(0.02, lo=0.005, hi=0.1, doc="grid the clean road is searched on (m)")
    max_shade: float = field(0.12, lo=0.0, hi=10.0, doc="windows whose lightness, blurred over "
                             f"{SHADE_SCALE_M * 100:g} cm, varies more than this fraction of its mean are "
                             "shade, not road")
    uniform: bool = field(True, doc="bring each window to its coarsest photo sample everywhere (else its near end "
                          "is sharper than its far end, and that shows at every repeat)")
    road_albedo: float = field(0.12, lo=0.0, hi=1.0, doc="linear luminance the surfaces' median is scaled to (one "
                               "factor for all: lighter and darker surfaces stay so; asphalt_worn: 0.12); 0 keeps "
                               "the photos' exposure")
    quilt: bool = field(True, doc=f"a window smaller than {ST_TILE_M:g} m makes the tile by image quilting (with "
                        "the windows of its kind of road) instead of repeating k x k (a band every window)")
    sources: int = field(4, lo=1, hi=16, doc="windows a quilted surface draws its blocks from: its own and the "
                         "nearest in colour and contrast")
    same_road: float = field(1.0, lo=0.0, hi=10.0, doc="farthest (standardised L*, chroma, contrast) another "
                             "frame's window may be from the surface's own to lend it blocks")
    patch_m: float = field(0.5, lo=0.05, hi=ST_TILE_M / 2, doc="quilting block side (m), a sixth more with its "
                           "overlap")
    flatten_m: float = field(0.25, lo=0.0, hi=ST_TILE_M, doc="quilting: colour that varies over more than this "
                             "(m, a Gaussian's sigma) is flattened in its windows (it would band every repeat); 0 "
                             "keeps it")
    seed: int = field(0, lo=0, hi=2**31 - 1, doc="seed of the quilting's choices among equally good blocks")


@dataclass
class Candidate:
    image: Path
    label: Path
    repeats: int                     # k: the window is ST_TILE_M / k a side
    row0: int                        # the search square (search grid texels)
    col0: int
    clean_m: float                   # side of the frame's largest clean square (m)
    features: np.ndarray             # mean L*, chroma, contrast (8-bit Lab)
    gsd_m: float = 0.0               # the window's worst ground sample (m per pixel)
    shade: float = 0.0               # decimetre-scale light variation / mean lightness


@dataclass
class SurfacesResult:
    surfaces: list[Surface]
    skipped: list[dict] = dc_field(default_factory=list)
    frames: int = 0
    rig: PhotoRig | None = None


class PhotoSurfaces:
    name = "photo_surfaces"
    description = "labelled road photos + camera rig -> seamless asphalt materials cut from defect-free road"
    produces = "materials"
    Params = PhotoSurfacesParams

    def run(self, inputs: dict[str, Any], params: PhotoSurfacesParams | None = None) -> SurfacesResult:
        p = check_params(params or PhotoSurfacesParams(), self.name)
        rig = rig_from(inputs.get("rig"))
        road_ids = [int(k) for k in (inputs.get("road_classes") or {})]
        defect_ids = [int(k) for k in (inputs.get("classes") or {})]
        if not road_ids:
            raise RoadtwinError(f"{inputs.get('classmap_source', 'class map')}: no road class (no class is filled from "
                                "the roadtwin label 'driving'): no road to cut surfaces from")
        pairs = frame_pairs(inputs)
        cp = CleanParams(p.search_texel_m, p.max_gsd_m, p.border_px, p.defect_margin_m, p.paint_margin_m,
                         p.paint_lightness, p.max_chroma)
        progress = inputs.get("progress") or (lambda done, total: None)
        views: dict[tuple[int, int], SearchView] = {}
        candidates, skipped = [], []
        for i, (img, lab) in enumerate(pairs):
            rgb, label = read_rgb(img), read_label(lab)
            if label.shape != rgb.shape[:2]:
                raise RoadtwinError(f"{lab}: label is {label.shape[1]}x{label.shape[0]} px, its image {img} is "
                                    f"{rgb.shape[1]}x{rgb.shape[0]}")
            h, w = label.shape
            view = views.get((w, h)) or views.setdefault((w, h), search_view(rig, w, h, cp))
            found = _candidate(img, lab, rgb, label, road_ids, defect_ids, view, cp, p)
            if isinstance(found, Candidate):
                candidates.append(found)
            else:
                skipped.append({"image": str(img), "why": found})
            progress(i + 1, len(pairs))
        if not candidates:
            where = pairs[0][0] if len(pairs) == 1 else f"{len(pairs)} frames"
            raise RoadtwinError(f"{where}: no clean road area of at least {p.min_window_m * (1 + p.overlap):.2f} m a "
                                f"side ({skipped[0]['why'] if len(pairs) == 1 else 'in any of them'}): nothing to cut")
        chosen = select(candidates, p.count)
        pool = sharp_pool(candidates, p.count)
        scale = np.array([c.features for c in candidates]).std(axis=0) + 1e-9
        surfaces, names = [], set()
        for i, c in enumerate(chosen):
            name = _unique(safe_prim_name(f"photo_{c.image.stem.split('_')[0]}"), names)
            license_text = inputs.get("license") or license_for(c.image)
            if p.quilt and c.repeats > 1:
                group = same_road(c, pool, chosen, p.sources, p.same_road, scale)
                rng = np.random.default_rng([p.seed, i])
                surfaces.append(quilt_surface(name, group, rig, views, p, inputs.get("license"), rng))
            else:
                surfaces.append(cut_surface(name, c, rig, views, p, license_text))
        if p.road_albedo > 0:
            factor = p.road_albedo / max(float(np.median([linear_luminance(s.tile) for s in surfaces])), 1e-4)
            surfaces = [as_albedo(s, factor) for s in surfaces]
        return SurfacesResult(surfaces, skipped, len(pairs), rig)

    def write(self, result: SurfacesResult, out: str | Path) -> list[Path]:
        """The three PNGs of every surface and ``materials.json`` in ``out`` (replaced atomically)."""
        import cv2

        paths = []
        with atomic_output_dir(out) as tmp:
            records = []
            for s in result.surfaces:
                n = s.tile.shape[0]
                files = {k: f"{s.name}_{k}.png" for k in ("diffuse", "roughness", "normal")}
                rough = cv2.resize(s.roughness.astype(np.float32), (max(16, n // 4),) * 2, interpolation=cv2.INTER_AREA)
                nrm = cv2.resize(s.normal.astype(np.float32), (max(16, n // 2),) * 2, interpolation=cv2.INTER_AREA)
                nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
                ok = cv2.imwrite(str(tmp / files["diffuse"]), cv2.cvtColor(s.tile, cv2.COLOR_RGB2BGR))
                ok &= cv2.imwrite(str(tmp / files["roughness"]), (np.clip(rough, 0, 1) * 255 + 0.5).astype(np.uint8))
                ok &= cv2.imwrite(str(tmp / files["normal"]), cv2.cvtColor(encode_normal(nrm), cv2.COLOR_RGB2BGR))
                if not ok:
                    raise RoadtwinError(f"{out}: cannot write the textures of {s.name}")
                records.append({"name": s.name, **files, **s.record})
                paths += [Path(out) / f for f in files.values()]
            meta = {"reconstructor": self.name, "st_tile_m": ST_TILE_M, "frames": result.frames,
                    "rig": asdict(result.rig) if result.rig else None, "materials": records,
                    "skipped": result.skipped}
            (tmp / MATERIALS_FILE).write_text(json.dumps(meta, indent=1))
        return paths + [Path(out) / MATERIALS_FILE]


def _unique(name: str, names: set[str]) -> str:
    base, k = name, 2
    while name in names:
        name, k = f"{base}_{k}", k + 1
    names.add(name)
    return name


def window_repeats(clean_m: float, p: PhotoSurfacesParams) -> int | None:
    """The smallest k (the biggest window, ST_TILE_M / k a side) whose window and blend overlap
    fit a clean square of ``clean_m``; None when even ``min_window_m`` does not."""
    k = max(1, math.ceil(ST_TILE_M * (1 + p.overlap) / max(clean_m, 1e-9)))
    return k if ST_TILE_M / k >= p.min_window_m - 1e-9 else None


def _search_side(k: int, p: PhotoSurfacesParams) -> int:
    """Search-grid texels a window of ST_TILE_M / k with its overlap needs (one spare texel)."""
    return math.ceil(ST_TILE_M / k * (1 + p.overlap) / p.search_texel_m) + 1


def _candidate(img: Path, lab: Path, rgb: np.ndarray, label: np.ndarray, road_ids, defect_ids, view: SearchView,
               cp: CleanParams, p: PhotoSurfacesParams) -> Candidate | str:
    """The frame's best window, or why there is none."""
    import cv2

    clean = clean_area(rgb, label, road_ids, defect_ids, view, cp)
    side, _, _ = largest_square(clean)
    clean_m = side * p.search_texel_m
    k = window_repeats(clean_m, p)
    at = None if k is None else square_at(clean, _search_side(k, p))
    while k is not None and at is None and ST_TILE_M / (k + 1) >= p.min_window_m - 1e-9:
        k += 1                                   # the square's grid rounding: one size down
        at = square_at(clean, _search_side(k, p))
    if k is None or at is None:
        return f"largest clean road square {clean_m:.2f} m (defect-, paint- and edge-free, well seen)"
    s = _search_side(k, p)
    colour = cv2.remap(rgb, view.map_u, view.map_v, cv2.INTER_LINEAR)[at[0]:at[0] + s, at[1]:at[1] + s]
    lab3 = cv2.cvtColor(colour, cv2.COLOR_RGB2LAB).astype(np.float64)
    lightness = lab3[..., 0]
    chroma = np.hypot(lab3[..., 1] - 128, lab3[..., 2] - 128)
    # light that changes over decimetres is shade (trees, poles), not the road: it would repeat
    shade = float(gaussian_filter(lightness, SHADE_SCALE_M / p.search_texel_m).std() / max(lightness.mean(), 1.0))
    if shade > p.max_shade:
        return f"light varies by {shade:.2f} of its mean over the window (shade; max_shade {p.max_shade:g})"
    features = np.array([lightness.mean(), chroma.mean(), lightness.std()])
    gsd = float(view.gsd[at[0]:at[0] + s, at[1]:at[1] + s].max())
    return Candidate(img, lab, k, at[0], at[1], clean_m, features, gsd, shade)


def select(candidates: list[Candidate], count: int) -> list[Candidate]:
    """Up to ``count`` candidates: the sharper half (window ground sample at most the median)
    when it holds ``count``; the biggest windows first (fewest repeats); within that, greedy
    farthest-point in standardised features, starting from the frame with the most clean road."""
    pool = sorted(sharp_pool(candidates, count), key=lambda c: (c.repeats, -c.clean_m, str(c.image)))
    chosen = [pool[0]]
    rest = pool[1:]
    feats = np.array([c.features for c in candidates])
    scale = feats.std(axis=0) + 1e-9
    while rest and len(chosen) < count:
        best_k = min(c.repeats for c in rest)
        tier = [c for c in rest if c.repeats == best_k]
        dist = [min(np.linalg.norm((c.features - q.features) / scale) for q in chosen) for c in tier]
        pick = tier[int(np.argmax(dist))]
        chosen.append(pick)
        rest.remove(pick)
    return chosen


def sharp_pool(candidates: list[Candidate], count: int) -> list[Candidate]:
    """The candidates whose window ground sample is at most the median, when they are ``count``."""
    sharp = [c for c in candidates if c.gsd_m <= float(np.median([q.gsd_m for q in candidates]))]
    return sharp if len(sharp) >= count else candidates
