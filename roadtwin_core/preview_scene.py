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
VIEW_BEHIND_M = 5.0      # ... and no more than this behind it


@dataclass
class PreviewTown:
    layout: TownLayout
    merged: list[MergedSegment]
    owners: list[list[int]]
    placements: list[Placement]
    markings: list = field(default_factory=list)
    looks_layer: Path | None = None
    _parts: list | None = None

    def lanes(self):
        from .render import Lane

        return [Lane(s.id, np.asarray(s.centerline, float)) for s in self.layout.segments
                if s.kind == "driving" and s.centerline is not None and len(s.centerline) >= 2]

    def _pieces(self):
        """(vertices, faces, kind-or-type, instance (0 = none), material name, st-fn) per piece."""
        if self._parts is not None:
            return self._parts
        from .usd.stage import planar_st
        from .usd.town import segment_st

        parts = []
        for seg, m, own in zip(self.layout.segments, self.merged, self.owners):
            road = m.face_owner < 0
            parts.append((m.vertices, m.faces[road], seg.kind, 0, kind_material(seg.kind),
                          (lambda v, seg=seg: segment_st(seg, v))))
            if road.all():
                continue
            for local in np.unique(m.face_owner[~road]):
                p_index = own[int(local)]
                p = self.placements[p_index]
                parts.append((m.vertices, m.faces[m.face_owner == local], p.model.defect_type, p_index + 1,
                              defect_material(p.model.defect_type), planar_st))
        for mk in self.markings:
            parts.append((mk.vertices, mk.faces, "lane_marking", 0, marking_material(mk.color), planar_st))
        self._parts = parts
        return parts

    def _instances(self, classes):
        return [{"id": k, "defect_id": p.instance_id, "type": p.model.defect_type,
                 "class_id": classes.index(p.model.defect_type),
                 "attributes": {"poseXYYaw": [p.x, p.y, p.yaw]}} for k, p in enumerate(self.placements, 1)]

    def _mesh(self, keep=None, looks: bool = False):
        from .render.scene import DEFAULT_MATERIAL, RenderMesh, class_names, render_material

        parts = self._pieces()
        dtypes = sorted({p.model.defect_type for p in self.placements})
        classes = class_names(dtypes, [s.kind for s in self.layout.segments])
        cid = {n: i for i, n in enumerate(classes)}
        materials, mat_index = [DEFAULT_MATERIAL], {}
        stage_mats = _stage_materials(self.looks_layer) if looks else {}
        verts, faces, fcls, finst, fmat, fuv, offset = [], [], [], [], [], [], 0
        for v, f, label, inst, mat, st_fn in parts:
            if keep is not None:
                f = f[keep(v, f)]
            if not len(f):
                continue
            used, inverse = np.unique(f, return_inverse=True)
            vv, ff = v[used], inverse.reshape(-1, 3)
            verts.append(vv)
            faces.append(ff + offset)
            offset += len(vv)
            n = len(ff)
            fcls.append(np.full(n, cid[label], np.int32))
            finst.append(np.full(n, inst, np.int32))
            m_id = 0
            if looks and mat in stage_mats:
                if mat not in mat_index:
                    mat_index[mat] = len(materials)
                    materials.append(render_material(stage_mats[mat]))
                m_id = mat_index[mat]
            fmat.append(np.full(n, m_id, np.int32))
            fuv.append(np.asarray(st_fn(vv), np.float32)[ff] if looks else None)
        uv = np.concatenate(fuv) if looks else np.zeros((sum(map(len, faces)), 3, 2), np.float32)
        return RenderMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(fcls), np.concatenate(finst),
                          np.concatenate(fmat), uv, classes, materials, self._instances(classes),
                          [c for c in classes if c in dtypes], str(self.layout.source))

    def map_mesh(self):
        """The whole town, labelled (no looks: the map colours by elevation and label)."""
        return self._mesh()

    def view_mesh(self, spot, range_m: float = VIEW_RANGE_M):
        """The road within ``range_m`` of the camera (and not behind it), with the stage's looks."""
        c, s = np.cos(spot.heading), np.sin(spot.heading)

        def keep(v, f):
            d = v[:, :2] - spot.xy
            ok = (np.hypot(d[:, 0], d[:, 1]) < range_m) & (d[:, 0] * c + d[:, 1] * s > -VIEW_BEHIND_M)
            return ok[f].any(axis=1)

        return self._mesh(keep, looks=True)


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


__all__ = ["PreviewTown", "VIEW_RANGE_M"]
