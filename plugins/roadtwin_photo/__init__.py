"""Defects from photos: labelled road photos + a known camera rig -> textured defect library assets.

Registers the reconstructor ``photo_defects`` (produces ``"defects"``), run by
``roadtwin reconstruct photos IMAGES... --labels DIR --classmap builtin:road_defects_br --rig survey -o LIBRARY``.

For each image, its label (``LABELS/<image stem>.png``, one dataset class id per pixel, the same
size as the image) is split into instances: the 8-connected components of each *defect class*
(a class the class map fills from a roadtwin defect type: for ``road_defects_br``, crack and
pothole; crack strokes closer than ``join_px`` make one instance). Each instance's pixels are
back-projected through the rig onto the flat road (:mod:`.rectify`), and :mod:`.patch` makes its
footprint in metres, an orthographic texture patch (albedo with an alpha fade into the road,
roughness and normal maps derived from it) and a mesh on the footprint (potholes get a depth from
a per-type prior with ravelled walls, a pothole label that is a strip along travel the 1-3 cm of
surface course it lost; cracks stay flush, their grooves in the normal map, and
their mesh is the label's strokes, :mod:`.strokes`: the renderer labels a defect's whole mesh, so
a crack is labelled as thin as the photo's strokes, not over the area they span). :meth:`PhotoDefects.write` writes one library asset per
instance (``roadtwin_core.usd.write_defect_asset``: interface + payloaded geometry, read back by
``compose --library``) plus the asset's ``primvars:st``, a ``UsdPreviewSurface`` bound to it, its
three textures under ``textures/`` and ``instances.json``; ``roadtwin:source`` names the frame,
the instance and the frame's license.

Inputs of ``run(inputs, params)``: the dict of ``roadtwin_core.apps.reconstruct.PhotoSet.as_dict()``,
which the command builds (it resolves the class map and the rig preset, which only the core
knows): ``images`` (paths), ``labels`` (folder), ``classes`` ({class id: (class name, defect
type)}, the class map's defect classes), ``rig`` (a :class:`PhotoRig` or its fields as a dict),
``license`` (optional text; default: the first line of a LICENSE file in the image's folder or up
to three folders above it).

Everything is checked and computed in ``run`` (an image without its label, a label of another
size, no defect class, a labelled pixel whose ray misses the road: one RoadtwinError each) and
``write`` replaces the output folder atomically, so bad input leaves nothing half-written.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field as dc_field, replace
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Sdf

from roadtwin_core import DefectLook, DefectModel, RoadtwinError, check_params, field, hookimpl
from roadtwin_core.atomic import atomic_output_dir
from roadtwin_core.usd import safe_prim_name, write_defect_asset

from .lane_rig import rig_from_lanes
from .photo_io import frame_pairs, license_for, read_label, read_rgb, rig_from
from .patch import Patch, PatchParams, instance_seed, make_patch
from .rectify import OrthoGrid, PhotoRig, grid_around, pixel_ground_area, rectify
from .surfaces import PhotoSurfaces

__all__ = ["PhotoDefects", "PhotoDefectsParams", "PhotoResult", "PhotoRig", "OrthoGrid", "Patch", "grid_around",
           "make_patch", "pixel_ground_area", "rectify"]


@dataclass
class PhotoDefectsParams:
    texel_m: float = field(0.01, lo=0.001, hi=0.1, doc="texture patch resolution on the road (m per texel)")
    fade_m: float = field(0.04, lo=0.0, hi=0.5, doc="band outside the label where the texture fades into the road (m)")
    edge_m: float = field(0.04, lo=0.005, hi=0.5, doc="mesh edge length along the outline (m)")
    min_pixels: int = field(30, lo=1, hi=10**7, doc="instances with fewer labelled pixels are skipped")
    min_area_m2: float = field(0.01, lo=0.0, hi=100.0, doc="instances with a smaller footprint on the road are skipped")
    max_texels: int = field(2048, lo=64, hi=8192, doc="texture side cap (the texel grows for larger footprints)")
    depth_ratio: float = field(0.25, lo=0.0, hi=2.0, doc="pothole depth prior: depth = ratio x equivalent radius")
    min_depth_m: float = field(0.02, lo=0.0, hi=0.5, doc="pothole depth prior, lower clip (m)")
    max_depth_m: float = field(0.10, lo=0.0, hi=0.5, doc="pothole depth prior, upper clip (m)")
    wall_ratio: float = field(0.35, lo=0.01, hi=2.0, doc="pothole wall width / equivalent radius")
    strip_elongation: float = field(3.0, lo=0.0, hi=100.0, doc="a pothole label this many times longer than wide, "
                                    "along travel, is a ravelled wheel-path strip: depth and wall from its half-width, "
                                    "at most strip_max_depth_m (0: every pothole a bowl)")
    strip_angle_deg: float = field(30.0, lo=0.0, hi=90.0, doc="a strip's long axis at most this far from travel (deg)")
    strip_max_depth_m: float = field(0.03, lo=0.0, hi=0.5, doc="a strip's depth cap (m): the surface course it lost")
    ravel: float = field(0.35, lo=0.0, hi=1.0, doc="relative amplitude of the ravelled wall noise")
    lane_width_m: float = field(0.0, lo=0.0, hi=10.0, doc="> 0: each frame's camera pitch and height from its "
                                "lane lines (the class map's lane class, this wide in m; lane_rig.py), for photos "
                                "whose rig is not known per frame; a frame whose lane edges are not straight keeps "
                                "the rig. 0: the rig for every frame")
    road_albedo: float = field(0.12, lo=0.0, hi=1.0, doc="linear luminance the road around a defect is scaled to, "
                               "so the patch is an albedo like the town's asphalt (asphalt_worn: 0.12); 0 keeps the "
                               "photo's exposure")
    join_px: int = field(9, lo=0, hi=101, doc="crack labels: strokes closer than this (px, at the photo's size) "
                         "make one instance (morphological closing) before instances are split")
    crack_strokes: bool = field(True, doc="a crack asset's mesh, and so its rendered label, is the label's strokes "
                                "(joined by bridges, holes slit open: strokes.py), as thin as the real labels; "
                                "false: the area the closed strokes span, holes filled, plus the fade band (labels "
                                "about twice as wide as real ones)")
    stroke_gap_m: float = field(0.01, lo=0.002, hi=0.2, doc="crack strokes: width of the bridges joining an "
                                "instance's strokes and of the slits opening the road they enclose (m)")
    max_range_m: float = field(80.0, lo=1.0, hi=10000.0, doc="a labelled pixel whose ray meets the road farther "
                               "than this misses the road (error)")


@dataclass
class PhotoInstance:
    image: str
    label: str
    instance: int
    class_name: str
    defect_type: str
    pixels: int
    bbox_px: tuple[int, int, int, int]           # u0, v0, u1, v1 (inclusive)
    area_m2: float                               # the label's footprint on the road
    range_m: float                               # distance from the camera foot to the centroid
    patch: Patch
    model: DefectModel


@dataclass
class PhotoResult:
    instances: list[PhotoInstance]
    skipped: list[dict] = dc_field(default_factory=list)
    frames: int = 0
    rig: PhotoRig | None = None

    @property
    def models(self) -> list[DefectModel]:
        return [i.model for i in self.instances]


def _components(mask: np.ndarray, join_px: int, strokes: bool = False):
    """The 8-connected components of a class mask: ((x0, y0, width, height, pixels), the
    component's mask inside that box). ``join_px`` > 1 first closes gaps that narrow (crack
    strokes join into one instance, not each stroke on its own); with ``strokes`` an instance's
    mask is its labelled pixels only (the closing groups them), else the closed area."""
    import cv2

    m = mask.astype(np.uint8)
    if join_px > 1:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (join_px, join_px)))
    n, comp, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    for c in range(1, n):
        x0, y0, bw, bh, npx = (int(v) for v in stats[c])
        sub = comp[y0:y0 + bh, x0:x0 + bw] == c
        if strokes:
            sub &= mask[y0:y0 + bh, x0:x0 + bw]
            npx = int(sub.sum())
        yield (x0, y0, bw, bh, npx), sub


class PhotoDefects:
    name = "photo_defects"
    description = "labelled road photos + camera rig -> textured defect assets (back-projected onto the road)"
    produces = "defects"
    Params = PhotoDefectsParams

    def run(self, inputs: dict[str, Any], params: PhotoDefectsParams | None = None) -> PhotoResult:
        p, rig, classes, pairs = self._checked(inputs, params)
        pp = PatchParams(texel_m=p.texel_m, fade_m=p.fade_m, edge_m=p.edge_m, max_texels=p.max_texels,
                         depth_ratio=p.depth_ratio, min_depth_m=p.min_depth_m, max_depth_m=p.max_depth_m,
                         wall_ratio=p.wall_ratio, ravel=p.ravel, road_albedo=p.road_albedo,
                         crack_strokes=p.crack_strokes, stroke_gap_m=p.stroke_gap_m,
                         strip_elongation=p.strip_elongation, strip_angle_deg=p.strip_angle_deg,
                         strip_max_depth_m=p.strip_max_depth_m)
        names: set[str] = set()
        out: list[PhotoInstance] = []
        skipped: list[dict] = []
        for img, lab in pairs:
            out += self._frame(img, lab, classes, rig, p, pp, inputs.get("license") or license_for(img), names, skipped,
                               inputs.get("lane_classes") or {})
        if not out:
            raise RoadtwinError(f"no defect instance of at least {p.min_pixels} px in the labels of {len(pairs)} "
                                f"frame(s) (classes {', '.join(v[0] for v in classes.values())}): nothing to write")
        return PhotoResult(out, skipped, len(pairs), rig)

    def _checked(self, inputs: dict[str, Any], params: PhotoDefectsParams | None):
        """(params, rig, classes, [(image, label)]): everything checked before any pixel is read
        (a bad pair late in the list fails fast too)."""
        p = check_params(params or PhotoDefectsParams(), self.name)
        if p.min_depth_m > p.max_depth_m:
            raise RoadtwinError(f"{self.name}: min_depth_m {p.min_depth_m} > max_depth_m {p.max_depth_m}")
        rig = PhotoRig(**{**asdict(rig_from(inputs.get("rig"))), "max_range_m": p.max_range_m})
        classes = {int(k): tuple(v) for k, v in (inputs.get("classes") or {}).items()}
        if not classes:
            raise RoadtwinError(f"{inputs.get('classmap_source', 'class map')}: no defect class (no class is filled "
                                "from a roadtwin defect type such as pothole or crack): nothing to reconstruct")
        if p.lane_width_m > 0 and not inputs.get("lane_classes"):
            raise RoadtwinError(f"{inputs.get('classmap_source', 'class map')}: lane_width_m needs a lane class in "
                                "the class map (the class plain road inside the ego lane maps to)")
        pairs = frame_pairs(inputs)
        return p, rig, classes, pairs

    def _frame(self, img: Path, lab: Path, classes: dict, rig: PhotoRig, p: PhotoDefectsParams, pp: PatchParams,
               license_text: str, names: set[str], skipped: list[dict], lane_classes: dict) -> list[PhotoInstance]:
        """One photo's instances, numbered 1.. per photo over its classes; those too small to keep
        go to ``skipped``. A labelled pixel whose ray misses the road is an error even when its
        instance would be skipped (a bad rig should not pass silently)."""
        rgb = read_rgb(img)
        label = read_label(lab)
        if label.shape != rgb.shape[:2]:
            raise RoadtwinError(f"{lab}: label is {label.shape[1]}x{label.shape[0]} px, its image {img} is "
                                f"{rgb.shape[1]}x{rgb.shape[0]}")
        h, w = label.shape
        if p.lane_width_m > 0:
            lane = np.isin(label, [int(k) for k in lane_classes])
            rig = rig_from_lanes(lane, rig, p.lane_width_m) or rig
        stem = safe_prim_name(img.stem, empty="frame", lead="f")
        out: list[PhotoInstance] = []
        for cid in sorted(classes):
            cname, dtype = classes[cid]
            crack = dtype == "crack"
            for (x0, y0, bw, bh, npx), sub in _components(label == cid, p.join_px if crack else 0,
                                                          crack and p.crack_strokes):
                vs, us = np.nonzero(sub)
                us, vs = us + x0, vs + y0
                _, ok = rig.backproject(us.astype(float), vs.astype(float), w, h)
                if not ok.all():
                    j = int(np.flatnonzero(~ok)[0])
                    raise RoadtwinError(f"{img}: {cname} pixel ({us[j]}, {vs[j]}) looks above the road's horizon "
                                        f"or beyond {p.max_range_m:g} m through {rig.describe()}: its ray misses "
                                        "the road")
                why = {"image": str(img), "class": cname, "pixels": npx}
                if npx < p.min_pixels:
                    skipped.append({**why, "why": "fewer than min_pixels"})
                    continue
                k = len(out) + 1
                mask = np.zeros((h, w), bool)
                mask[y0:y0 + bh, x0:x0 + bw] = sub
                patch = make_patch(rgb, mask, rig, dtype, pp, instance_seed(str(img.name), k))
                if patch is None or patch.area_m2 < p.min_area_m2:
                    skipped.append({**why, "why": "footprint too small" + (
                        "" if patch is None else f" ({patch.area_m2:.4f} m2 < min_area_m2)")})
                    continue
                name = f"{stem}_{dtype}_{k:02d}"
                while name in names:
                    name += "_b"
                bbox = (x0, y0, x0 + bw - 1, y0 + bh - 1)
                range_m = float(np.hypot(*patch.centroid))
                record = {"reconstructor": self.name, "frame": str(img), "label": str(lab), "instance": k,
                          "class": cname, "pixels": npx, "bbox_px": list(bbox),
                          "footprint_area_m2": round(patch.area_m2, 6), "texel_m": patch.grid.texel,
                          "prior_depth_m": round(patch.depth_m, 5),
                          "relief": patch.relief, "rig": asdict(rig), "license": license_text,
                          "range_m": round(range_m, 3)}
                try:
                    model = DefectModel(name, dtype, patch.vertices, patch.faces, patch.boundary, params=record,
                                        source=f"photo {img} ({cname} instance {k}); license: {license_text}")
                except RoadtwinError:
                    skipped.append({**why, "why": "mesh degenerate"})
                    continue
                names.add(name)
                out.append(PhotoInstance(str(img), str(lab), k, cname, dtype, npx, bbox, patch.area_m2, range_m,
                                         patch, model))
        return out

    def reconstruct(self, inputs: dict[str, Any], params: PhotoDefectsParams | None = None) -> list[DefectModel]:
        return self.run(inputs, params).models

    def write(self, result: PhotoResult, out: str | Path) -> list[Path]:
        """One asset per instance (``NAME.usda`` + ``NAME.geom.usda``), ``textures/NAME_{diffuse,
        roughness,normal}.png`` and ``instances.json``, in ``out`` (replaced atomically)."""
        paths = []
        with atomic_output_dir(out) as tmp:
            (tmp / "textures").mkdir()
            meta = {"reconstructor": self.name, "frames": result.frames, "rig": asdict(result.rig) if result.rig else None,
                    "assets": [], "skipped": result.skipped}
            for inst in result.instances:
                write_photo_asset(inst.model, inst.patch, tmp / f"{inst.model.name}.usda")
                paths.append(Path(out) / f"{inst.model.name}.usda")
                meta["assets"].append({"name": inst.model.name, "image": inst.image, "class": inst.class_name,
                                       "type": inst.defect_type, "pixels": inst.pixels, "bbox_px": list(inst.bbox_px),
                                       "footprint_area_m2": inst.area_m2, "range_m": inst.range_m,
                                       **{k: v for k, v in inst.model.attributes().items() if k != "source"}})
            (tmp / "instances.json").write_text(json.dumps(meta, indent=1))
        return paths


def write_photo_asset(model: DefectModel, patch: Patch, path: Path) -> Path:
    """The textures under ``textures/NAME_{diffuse,roughness,normal}.png``, then the asset with them
    as its look (``write_defect_asset``: st on the mesh, a bound UsdPreviewSurface whose opacity
    is the albedo's alpha) and the patch's footprint area and texel size."""
    import cv2

    path = Path(path)
    tex_dir = path.parent / "textures"
    tex_dir.mkdir(exist_ok=True)
    files = {role: tex_dir / f"{model.name}_{role}.png" for role in ("diffuse", "roughness", "normal")}
    ok = cv2.imwrite(str(files["diffuse"]), cv2.cvtColor(patch.albedo, cv2.COLOR_RGBA2BGRA))
    ok &= cv2.imwrite(str(files["roughness"]), patch.roughness)
    ok &= cv2.imwrite(str(files["normal"]), cv2.cvtColor(patch.normal, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RoadtwinError(f"{tex_dir}: cannot write the textures of {model.name}")
    look = DefectLook.fit({role: str(f) for role, f in files.items()}, patch.vertices, patch.st)
    if look is None:
        raise RoadtwinError(f"{model.name}: the patch's st is not a planar map of the footprint")
    write_defect_asset(replace(model, look=look), path)
    layer = Sdf.Layer.FindOrOpen(str(path))
    root = layer.GetPrimAtPath(f"/{model.name}")
    for attr, value in (("roadtwin:photo:footprintAreaM2", patch.area_m2), ("roadtwin:photo:texelM", patch.grid.texel)):
        Sdf.AttributeSpec(root, attr, Sdf.ValueTypeNames.Double, Sdf.VariabilityVarying, True).default = float(value)
    layer.Save()
    return path


@hookimpl
def roadtwin_register_reconstructors(register):
    register(PhotoDefects())
    register(PhotoSurfaces())
