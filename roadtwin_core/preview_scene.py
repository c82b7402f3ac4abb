"""The town the composer just wrote, as the preview needs it, without reading the stage back.

Why: reading a 1,000-defect Town01 back with its looks (every mesh, every st primvar) and
building a ray-casting scene over its 1.8 M triangles took ~6-20 s; the preview needs the map
(geometry and labels only) and one view of the road around one camera. Geometry, labels and
st come from the composer's in-memory meshes, through the same functions the writer uses
(``segment_st`` / ``planar_st``, the catalog's binding rules); the materials themselves are
parsed from the stage's own looks layer (``layers/looks.usda``, a small file), so the view
shows the stage's materials. tests/test_preview_scene.py checks the result against
``build_render_mesh(load_town(stage, looks=True))``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .looks.catalog import defect_material, kind_material, marking_material
from .model import MergedSegment, Placement, TownLayout

VIEW_RANGE_M = 150.0     # road drawn in the perspective view: this far around the camera ...
VIEW_BEHIND_M = 5.0      # ... and no more than this behind it (without a view wedge)
VIEW_MARGIN_M = 2.0      # faces this close to the camera's view wedge are kept (shadows, bevels)


@dataclass
class PreviewTown:
    layout: TownLayout
    merged: list[MergedSegment]
    owners: list[list[int]]
    placements: list[Placement]
    markings: list = field(default_factory=list)
    looks_layer: Path | None = None
    # material name -> parsed TownMaterial (what ``_stage_materials`` reads from the looks
    # layer): a caller that holds them renders before ``layers/looks.usda`` is on disk
    materials: dict | None = None

    def stage_materials(self) -> dict:
        """Material name -> parsed ``TownMaterial``: ``materials`` when given, else the looks layer's."""
        return self.materials if self.materials is not None else _stage_materials(self.looks_layer)

    def lanes(self):
        from .render import Lane

        return [Lane(s.id, np.asarray(s.centerline, float)) for s in self.layout.segments
                if s.kind == "driving" and s.centerline is not None and len(s.centerline) >= 2]

    def _parts(self):
        """Per merged segment and per marking: (vertices, faces, class per face, instance per
        face, material name per face, st-function per face group). Whole segments at a time
        (numpy lookups by face owner), not one array per defect piece: a 10,000-defect town has
        ~12,000 pieces."""
        from .usd.stage import planar_st
        from .usd.town import segment_st

        for seg, m, own in zip(self.layout.segments, self.merged, self.owners):
            own = np.asarray(own, dtype=np.int64)
            is_defect = m.face_owner >= 0
            placement = np.where(is_defect, own[np.maximum(m.face_owner, 0)] if len(own) else -1, -1)
            yield (m.vertices, m.faces, seg.kind, placement, kind_material(seg.kind),
                   (lambda v, seg=seg: segment_st(seg, v)), planar_st)
        for mk in self.markings:
            yield (mk.vertices, mk.faces, "lane_marking", np.full(len(mk.faces), -1), marking_material(mk.color),
                   planar_st, planar_st)

    def _instances(self, classes):
        return [{"id": k, "defect_id": p.instance_id, "type": p.model.defect_type,
                 "class_id": classes.index(p.model.defect_type),
                 "attributes": {"poseXYYaw": [p.x, p.y, p.yaw]}} for k, p in enumerate(self.placements, 1)]

    def _mesh(self, keep=None, looks: bool = False):
        from .render.scene import DEFAULT_MATERIAL, RenderMesh, class_names, render_material

        dtypes = sorted({p.model.defect_type for p in self.placements})
        classes = class_names(dtypes, [s.kind for s in self.layout.segments])
        cid = {n: i for i, n in enumerate(classes)}
        stage_mats = self.stage_materials() if looks else {}
        materials = [DEFAULT_MATERIAL]
        mat_slot = {}                                  # material name -> index in ``materials``
        p_class = np.array([cid[p.model.defect_type] for p in self.placements] or [0], np.int32)
        p_mat = [defect_material(p.model.defect_type) for p in self.placements]

        def slot(name: str) -> int:
            if name not in stage_mats:
                return 0
            if name not in mat_slot:
                mat_slot[name] = len(materials)
                materials.append(preview_material(stage_mats[name]) if looks else render_material(stage_mats[name]))
            return mat_slot[name]

        verts, faces, fcls, finst, fmat, fuv, offset = [], [], [], [], [], [], 0
        for v, f, label, placement, mat, road_st, defect_st in self._parts():
            sel = keep(v, f) if keep is not None else np.ones(len(f), bool)
            if not sel.any():
                continue
            f, placement = f[sel], placement[sel]
            defect = placement >= 0
            cls = np.where(defect, p_class[np.maximum(placement, 0)], cid[label]).astype(np.int32)
            verts.append(v)
            faces.append(f + offset)
            offset += len(v)
            fcls.append(cls)
            finst.append((placement + 1).astype(np.int32))
            if looks:
                # decode only the materials in view (a 1024 px material is ~30 MB as float images)
                used = np.unique(placement[defect])
                lut = np.zeros(max(len(p_mat), 1), np.int32)
                lut[used] = [slot(p_mat[i]) for i in used]
                road_slot = slot(mat) if (~defect).any() else 0
                fmat.append(np.where(defect, lut[np.maximum(placement, 0)], road_slot).astype(np.int32))
                uv = np.asarray(road_st(v), np.float32)[f]
                if defect.any():
                    uv[defect] = np.asarray(defect_st(v), np.float32)[f[defect]]
                fuv.append(uv)
            else:
                fmat.append(np.zeros(len(f), np.int32))
        uv = np.concatenate(fuv) if looks else np.zeros((sum(map(len, faces)), 3, 2), np.float32)
        return RenderMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(fcls), np.concatenate(finst),
                          np.concatenate(fmat), uv, classes, materials, self._instances(classes),
                          [c for c in classes if c in dtypes], str(self.layout.source))

    def map_mesh(self):
        """The whole town, labelled (no looks: the map colours by elevation and label)."""
        return self._mesh()

    def view_mesh(self, spot, range_m: float = VIEW_RANGE_M, half_angle: float | None = None):
        """The road within ``range_m`` of the camera, with the stage's looks: only faces that
        may lie inside the horizontal wedge of ``half_angle`` (rad) about the heading (None:
        everything not more than ``VIEW_BEHIND_M`` behind the camera). A face is kept when its
        bounding circle (centroid, farthest corner) meets the region, so a large road triangle
        whose corners all lie outside the wedge is still drawn."""
        c, s = np.cos(spot.heading), np.sin(spot.heading)
        wedge = half_angle is not None and half_angle < 0.5 * np.pi

        def keep(v, f):
            lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)     # whole segment out of range: skip
            if (np.maximum(lo - spot.xy, 0) ** 2).sum() + (np.maximum(spot.xy - hi, 0) ** 2).sum() >= range_m ** 2:
                return np.zeros(len(f), bool)
            d = v[:, :2] - spot.xy
            if not wedge:
                ok = (np.hypot(d[:, 0], d[:, 1]) < range_m) & (d[:, 0] * c + d[:, 1] * s > -VIEW_BEHIND_M)
                return ok[f[:, 0]] | ok[f[:, 1]] | ok[f[:, 2]]
            ca, cb, cc = d[f[:, 0]], d[f[:, 1]], d[f[:, 2]]
            cen = (ca + cb + cc) / 3.0
            r = np.sqrt(np.maximum(np.maximum(((ca - cen) ** 2).sum(1), ((cb - cen) ** 2).sum(1)),
                                   ((cc - cen) ** 2).sum(1)))
            ahead = cen[:, 0] * c + cen[:, 1] * s
            side = np.abs(-cen[:, 0] * s + cen[:, 1] * c)
            dist = np.hypot(ahead, side)
            off = np.arctan2(side, ahead) - half_angle               # angle outside the wedge
            to_wedge = np.where(off <= 0, 0.0, np.where(off < 0.5 * np.pi, dist * np.sin(np.minimum(off, 0.5 * np.pi)),
                                                         dist))
            return (to_wedge <= r + VIEW_MARGIN_M) & (dist - r < range_m)

        return self._mesh(keep, looks=True)


PREVIEW_TEXELS = 512     # textures decoded at the MIP level no larger than this (one small frame)


def preview_material(mat, max_texels: int = PREVIEW_TEXELS):
    """A stage material as the renderer's images, each texture at the first MIP level whose
    side is <= ``max_texels``: the renderer's own box pyramid level (2 x 2 means of the
    decoded values), so the view looks as the full material does at that distance, for a
    quarter of the memory per level dropped. Decoded through a 256-entry table (uint8 in)."""
    from .render.scene import RenderMaterial

    diffuse = (_decode_reduced(mat.diffuse_texture, max_texels) if mat.diffuse_texture is not None
               else np.asarray(mat.diffuse_color, np.float32).reshape(1, 1, 3))
    rough = (_decode_reduced(mat.roughness_texture, max_texels) if mat.roughness_texture is not None
             else np.full((1, 1, 1), mat.roughness, np.float32))
    normal = _decode_reduced(mat.normal_texture, max_texels) if mat.normal_texture is not None else None
    first = next((t for t in (mat.diffuse_texture, mat.roughness_texture, mat.normal_texture) if t is not None), None)
    wrap = (first.wrap_s, first.wrap_t) if first is not None else ("repeat", "repeat")
    return RenderMaterial(mat.name, np.clip(diffuse, 0.0, None), np.clip(rough, 0.0, 1.0), normal,
                          mat.metallic, wrap)


def _decode_reduced(tex, max_texels: int) -> np.ndarray:
    """``decode_texture(tex)`` box-reduced by 2 until its larger side is <= ``max_texels``.
    8-bit files go through OpenCV (its PNG decode is faster than Pillow's, and it releases the
    GIL); values are decoded through a 256-entry table and box-reduced by ``cv2.resize``
    (INTER_AREA at a power-of-two factor is the mean of each 2^k x 2^k block, as the repeated
    2 x 2 means of the renderer's pyramid)."""
    import cv2

    from .errors import RoadtwinError
    from .usd.looks_reader import decode_texture, srgb_to_linear

    if not tex.path:
        return decode_texture(tex)
    img = cv2.imread(str(tex.path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RoadtwinError(f"{tex.path}: not a readable image")
    if img.dtype != np.uint8 or (img.ndim == 3 and img.shape[2] not in (3, 4)):
        out = decode_texture(tex)                          # 16-bit and others: the general path
    else:
        # OpenCV's channel order (grey, BGR, BGRA) as the RGBA the texture's channels index
        planes = ([img] * 3 + [None]) if img.ndim == 2 else [img[..., 2], img[..., 1], img[..., 0],
                                                              img[..., 3] if img.shape[2] == 4 else None]
        unit = np.arange(256, dtype=np.float32) / 255.0
        lin = srgb_to_linear(unit)
        out = np.empty(img.shape[:2] + (len(tex.channels),), np.float32)
        for k, ch in enumerate(tex.channels):
            scale, bias = np.float32(tex.scale[k]), np.float32(tex.bias[k])
            lut = (lin if tex.srgb and ch < 3 else unit) * scale + bias
            if planes[ch] is None:                           # no alpha in the file: opaque
                out[..., k] = lut[255]
            else:
                out[..., k] = np.take(lut, planes[ch])
    h, w = out.shape[:2]
    k = 1
    while max(h, w) // k > max_texels and (h // k) % 2 == 0 and (w // k) % 2 == 0:
        k *= 2
    if k > 1:
        small = cv2.resize(out, (w // k, h // k), interpolation=cv2.INTER_AREA)
        out = small.reshape(h // k, w // k, out.shape[2])
    return np.ascontiguousarray(out, dtype=np.float32)


def materials_from_specs(specs: dict, layers_dir: Path, root: str) -> dict:
    """Material name -> parsed ``TownMaterial`` of the looks layer that ``write_looks`` will
    write into ``layers_dir`` for ``specs`` (``MaterialSpec`` by name), without waiting for it:
    the same ``define_material`` network, parsed by the same reader, on an in-memory layer
    anchored in ``layers_dir`` (so its ``../textures`` paths resolve; the textures must be there)."""
    from pxr import Sdf, Usd, UsdShade

    from .usd.looks import define_material
    from .usd.looks_reader import parse_material

    layer = Sdf.Layer.New(Sdf.FileFormat.FindByExtension("usda"), str(Path(layers_dir) / "_preview_looks.usda"))
    try:
        stage = Usd.Stage.Open(layer)
        out = {}
        for name in sorted(specs):
            mat = define_material(stage, root, specs[name])
            out.setdefault(mat.GetPrim().GetName(), parse_material(UsdShade.Material(mat.GetPrim())))
        del stage
    finally:
        layer.Clear()
    return out


def _stage_materials(looks_layer: Path | None) -> dict:
    """Material name -> parsed ``TownMaterial`` of every ``UsdShade.Material`` in the looks layer."""
    if looks_layer is None or not Path(looks_layer).exists():
        return {}
    from pxr import Usd, UsdShade

    from .usd.looks_reader import parse_material

    stage = Usd.Stage.Open(str(looks_layer))
    out = {}
    for prim in stage.Traverse():
        if prim.IsA(UsdShade.Material):
            out.setdefault(prim.GetName(), parse_material(UsdShade.Material(prim)))
    return out


__all__ = ["PreviewTown", "VIEW_RANGE_M", "materials_from_specs", "preview_material"]
