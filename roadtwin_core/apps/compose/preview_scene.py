"""The town the composer just wrote, as the preview needs it, without reading the stage back.

Why: reading a 1,000-defect Town01 back with its looks (every mesh, every st primvar) and
building a ray-casting scene over its 1.8 M triangles took ~6-20 s; the preview needs the map
(geometry and labels only) and one view of the road around one camera. Geometry, labels and
st come from the composer's in-memory meshes, through the same functions the writer uses
(``segment_st`` / ``planar_st``, the catalog's binding rules); the materials themselves are
parsed from the stage's own looks layer (``layers/looks.usda``, a small file, which the composer
writes first), so the view shows the stage's materials.
tests/apps/test_preview_scene.py checks the result against ``build_render_mesh(load_town(stage, looks=True))``
without its props: the preview draws the road, defects and markings, not the roadside world
(``layers/props.usda``).

Cost (Town01, 1,000 defects, 2 cores): the parts are concatenated once (~0.05 s) and the map
and the view are selected from that with whole-array culling; decoding the ~10 materials in
view (PNG, 28 files) is the largest piece left (~0.2 s).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Usd, UsdShade

from ...errors import RoadtwinError
from ...looks.catalog import kind_material, marking_material
from ...model import MergedSegment, Placement, TownLayout
from ...render import Lane
from ...render.scene import DEFAULT_MATERIAL, RenderMaterial, RenderMesh, class_names
from ...usd.looks_reader import decode_texture, parse_material, srgb_to_linear
from ...usd.stage import planar_st
from ...usd.town import defect_material_name, defect_st, segment_st

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
    defect_materials: dict[str, str] = field(default_factory=dict)   # defect type -> catalog material
    _geometry: object = field(default=None, init=False, repr=False, compare=False)

    def lanes(self):
        return [Lane(s.id, np.asarray(s.centerline, float)) for s in self.layout.segments
                if s.kind == "driving" and s.centerline is not None and len(s.centerline) >= 2]

    def _parts(self):
        """Per merged segment and per marking: (vertices, faces, class per face, instance per
        face, material name per face, st-function per face group). Whole segments at a time
        (numpy lookups by face owner), not one array per defect piece: a 10,000-defect town has
        ~12,000 pieces."""
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

    def _town(self) -> "_Geometry":
        """The whole town concatenated once (then kept): what the map draws and the view
        selects from, so neither does per-part Python work beyond the parts it keeps."""
        if getattr(self, "_geometry", None) is None:
            verts, faces, fpart, fplace, labels, mats, road_sts, vstart = [], [], [], [], [], [], [], [0]
            for v, f, label, placement, mat, road_st, _defect_st in self._parts():
                if not len(f):
                    continue
                fpart.append(np.full(len(f), len(labels), np.int32))
                faces.append(np.asarray(f, np.int64) + vstart[-1])
                verts.append(np.asarray(v, np.float64))
                fplace.append(np.asarray(placement, np.int64))
                labels.append(label)
                mats.append(mat)
                road_sts.append(road_st)
                vstart.append(vstart[-1] + len(v))
            v = np.concatenate(verts)
            starts = np.asarray(vstart, np.int64)
            self._geometry = _Geometry(v, np.concatenate(faces), np.concatenate(fpart), np.concatenate(fplace),
                                       labels, mats, road_sts, starts,
                                       np.minimum.reduceat(v[:, :2], starts[:-1], axis=0),
                                       np.maximum.reduceat(v[:, :2], starts[:-1], axis=0))
        return self._geometry

    def _labels(self, g):
        """(classes, defect types, class id per face)."""
        dtypes = sorted({p.model.defect_type for p in self.placements})
        classes = class_names(dtypes, [s.kind for s in self.layout.segments])
        cid = {n: i for i, n in enumerate(classes)}
        p_class = np.array([cid[p.model.defect_type] for p in self.placements] or [0], np.int32)
        part_class = np.array([cid[label] for label in g.labels], np.int32)
        return classes, dtypes, (p_class, part_class)

    def map_mesh(self):
        """The whole town, labelled (no looks: the map colours by elevation and label)."""
        g = self._town()
        classes, dtypes, (p_class, part_class) = self._labels(g)
        defect = g.place >= 0
        cls = np.where(defect, p_class[np.maximum(g.place, 0)], part_class[g.part])
        m = len(g.faces)
        return RenderMesh(g.vertices, g.faces, cls, (g.place + 1).astype(np.int32), np.zeros(m, np.int32),
                          np.zeros((m, 3, 2), np.float32), classes, [DEFAULT_MATERIAL], self._instances(classes),
                          [c for c in classes if c in dtypes], str(self.layout.source))

    def view_mesh(self, spot, range_m: float = VIEW_RANGE_M, half_angle: float | None = None):
        """The road within ``range_m`` of the camera, with the stage's looks: only faces that
        may lie inside the horizontal wedge of ``half_angle`` (rad) about the heading (None:
        everything not more than ``VIEW_BEHIND_M`` behind the camera). A face is kept when its
        bounding circle (centroid, farthest corner) meets the region, so a large road triangle
        whose corners all lie outside the wedge is still drawn. Parts (segments, markings)
        with any face kept bring all their vertices, in the town's order."""
        g = self._town()
        c, s = np.cos(spot.heading), np.sin(spot.heading)
        xy = np.asarray(spot.xy, np.float64)
        # parts wholly out of range are skipped by their boxes
        gap = (np.maximum(g.lo - xy, 0) ** 2).sum(axis=1) + (np.maximum(xy - g.hi, 0) ** 2).sum(axis=1)
        idx = np.flatnonzero((gap < range_m ** 2)[g.part])
        f = g.faces[idx]
        d = g.vertices[:, :2] - xy
        if half_angle is None or half_angle >= 0.5 * np.pi:
            ok = (np.hypot(d[:, 0], d[:, 1]) < range_m) & (d[:, 0] * c + d[:, 1] * s > -VIEW_BEHIND_M)
            sel = ok[f[:, 0]] | ok[f[:, 1]] | ok[f[:, 2]]
        else:
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
            sel = (to_wedge <= r + VIEW_MARGIN_M) & (dist - r < range_m)
        kept = idx[sel]
        part = g.part[kept]
        place = g.place[kept]
        parts = np.unique(part)                                      # ascending: the town's order
        count = g.vstart[parts + 1] - g.vstart[parts]
        new_start = np.concatenate([[0], np.cumsum(count)])
        shift = np.zeros(len(g.labels), np.int64)
        shift[parts] = g.vstart[parts] - new_start[:-1]
        faces = g.faces[kept] - shift[part][:, None]
        vidx = np.repeat(g.vstart[parts] - new_start[:-1], count) + np.arange(new_start[-1])
        vertices = g.vertices[vidx]
        classes, dtypes, (p_class, part_class) = self._labels(g)
        defect = place >= 0
        cls = np.where(defect, p_class[np.maximum(place, 0)], part_class[part])
        # st: each part's own road st (lane-aligned on driving segments), world-planar on defects
        road_st = np.concatenate([np.asarray(g.road_st[k](g.vertices[g.vstart[k]:g.vstart[k + 1]]), np.float32)
                                  for k in parts]) if len(parts) else np.zeros((0, 2), np.float32)
        uv = road_st[faces]
        if defect.any():
            uv[defect] = np.asarray(planar_st(vertices), np.float32)[faces[defect]]
            # textured models: their own st; faces grouped by placement once (not a scan per placement)
            order = np.flatnonzero(defect)[np.argsort(place[defect], kind="stable")]
            ks, starts = np.unique(place[order], return_index=True)
            for k, sel in zip(ks, np.split(order, starts[1:])):
                if self.placements[k].model.look is not None:
                    corners = vertices[faces[sel]].reshape(-1, 3)
                    uv[sel] = np.asarray(defect_st(self.placements[k], corners), np.float32).reshape(-1, 3, 2)
        # materials: only those of the faces kept, decoded once each (a 1024 px material is ~30 MB)
        stage_mats = _stage_materials(self.looks_layer)
        p_mat = [defect_material_name(p, self.defect_materials) for p in self.placements]
        names = sorted({p_mat[i] for i in np.unique(place[defect])} | {g.mats[k] for k in np.unique(part[~defect])})
        materials, slot = [DEFAULT_MATERIAL], {}
        for name in names:
            if name in stage_mats:
                slot[name] = len(materials)
                materials.append(preview_material(stage_mats[name]))
        part_slot = np.array([slot.get(m, 0) for m in g.mats], np.int32)
        place_slot = np.array([slot.get(m, 0) for m in p_mat] or [0], np.int32)
        fmat = np.where(defect, place_slot[np.maximum(place, 0)], part_slot[part])
        return RenderMesh(vertices, faces, cls, (place + 1).astype(np.int32), fmat, uv, classes, materials,
                          self._instances(classes), [c for c in classes if c in dtypes], str(self.layout.source))


@dataclass
class _Geometry:
    """The town's parts concatenated: per face its part and placement (-1: road); per part its
    label, road material, road st function, first vertex (``vstart``, one more at the end) and
    xy bounding box."""

    vertices: np.ndarray
    faces: np.ndarray
    part: np.ndarray
    place: np.ndarray
    labels: list
    mats: list
    road_st: list
    vstart: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


PREVIEW_TEXELS = 512     # textures decoded at the MIP level no larger than this (one small frame)


def preview_material(mat, max_texels: int = PREVIEW_TEXELS):
    """A stage material as the renderer's images, each texture at the first MIP level whose
    side is <= ``max_texels``: the renderer's own box pyramid level (2 x 2 means of the
    decoded values), so the view looks as the full material does at that distance, for a
    quarter of the memory per level dropped. Decoded through a 256-entry table (uint8 in)."""
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


def _stage_materials(looks_layer: Path | None) -> dict:
    """Material name -> parsed ``TownMaterial`` of every ``UsdShade.Material`` in the looks layer."""
    if looks_layer is None or not Path(looks_layer).exists():
        return {}
    stage = Usd.Stage.Open(str(looks_layer))
    out = {}
    for prim in stage.Traverse():
        if prim.IsA(UsdShade.Material):
            out.setdefault(prim.GetName(), parse_material(UsdShade.Material(prim)))
    return out


__all__ = ["PreviewTown", "VIEW_RANGE_M", "preview_material"]
