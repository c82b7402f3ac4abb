"""Per-frame scene looks on a :class:`RenderMesh`: the material side of domain randomization.

A :class:`~roadtwin_core.render.randomize.SceneLook` says "this frame: gravel verge, worn and
slightly warm asphalt, bluish sky". :class:`LookTable` turns that into plain arrays a renderer
applies per frame without rebuilding its scene (:class:`MaterialLook`):

- ``remap`` (n_materials,) material id -> the id whose textures are sampled: the verge and
  shoulder surfaces switch among the catalog's variants (``VERGE_MATERIAL_VARIANTS``,
  ``shoulder``, ``asphalt_worn``);
- ``albedo_scale`` (n_materials, 3): a diffuse multiplier per material (road tint and wear on the
  driving surface, the shoulder and the defects in it, so a pothole keeps the road's colour);
- ``sky_tint`` (3,): multiplies the sky's zenith and horizon colours.

Why material ids and not faces: a remap of a few dozen ids costs nothing per frame, while face
arrays are hundreds of thousands of entries. So that a remap never touches faces it should not,
each material used by faces of several groups (road / shoulder / verge / other; e.g. the grey
default of a stage without looks) is first split into one table entry per group
(:meth:`LookTable.split`; the entries share their images).

Variant textures come from the stage when it binds them (a material whose prim name is the
variant's name), else from ``textures/<name>_diffuse.png`` (+ ``_roughness``, ``_normal``)
beside the stage when present (what the looks writer puts there), else the variant is skipped
and the frame's record says so.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .scene import RenderMaterial, RenderMesh

ROAD_KINDS = ("driving", "junction")
SHOULDER_KINDS = ("shoulder",)
VERGE_KINDS = ("verge",)
GROUPS = ("road", "shoulder", "verge", "other")
WEAR_LIGHTEN = 0.35          # fully worn asphalt: oxidised binder, exposed aggregate, 35 % lighter


@dataclass(frozen=True)
class MaterialLook:
    remap: np.ndarray
    albedo_scale: np.ndarray
    sky_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    applied: dict = field(default_factory=dict)     # what was applied (for meta.json)


def _short(name: str) -> str:
    return name.rstrip("/").rsplit("/", 1)[-1]


def _load_variant(textures: Path, name: str) -> RenderMaterial | None:
    """A catalog material from the stage's textures/ folder (the looks writer's file names)."""
    from ..usd.looks_reader import TextureRef, decode_texture   # pxr (via roadtwin_core.usd): GPU side has no USD

    diffuse = textures / f"{name}_diffuse.png"
    if not diffuse.is_file():
        return None
    d = decode_texture(TextureRef(str(diffuse), (0, 1, 2), True, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.18,) * 3))
    rough_path, normal_path = textures / f"{name}_roughness.png", textures / f"{name}_normal.png"
    r = (decode_texture(TextureRef(str(rough_path), (0,), False, (1.0,), (0.0,), (0.8,)))
         if rough_path.is_file() else np.full((1, 1, 1), 0.8, np.float32))
    n = (decode_texture(TextureRef(str(normal_path), (0, 1, 2), False, (2.0,) * 3, (-1.0,) * 3, (0.0, 0.0, 1.0)))
         if normal_path.is_file() else None)
    return RenderMaterial(f"textures/{name}", np.clip(d, 0.0, None), np.clip(r, 0.0, 1.0), n)


class LookTable:
    """Which material ids a :class:`SceneLook` may change on one mesh (see the module doc).
    Build it with :meth:`split` (which returns the mesh to render as well)."""

    def __init__(self, mesh: RenderMesh, groups: dict[str, list[int]], variants: dict[str, int]):
        self.n = len(mesh.materials)
        self.groups = groups            # group -> material ids used by that group's faces
        self.variants = variants        # surface name -> material id
        # the built-in pothole interior (by the catalog's material name), whatever group it is in
        self.potholes = [i for i, m in enumerate(mesh.materials) if _short(m.name).split("#")[0] == "pothole"]

    @classmethod
    def split(cls, mesh: RenderMesh, stage_dir: str | Path | None = None,
              surfaces: tuple[str, ...] = ()) -> tuple[RenderMesh, "LookTable"]:
        """(mesh with group-private material ids and the variant materials appended, table).
        ``surfaces``: the verge / shoulder surface names a look may ask for."""
        kind_of = np.array([_group(c) for c in mesh.classes])
        # defects take the road's tint: their class is not a road kind, but their faces lie in it
        defect_ids = {mesh.classes.index(t) for t in mesh.defect_types if t in mesh.classes}
        face_group = kind_of[mesh.face_class]
        if defect_ids:
            face_group = np.where(np.isin(mesh.face_class, list(defect_ids)), "road", face_group)
        materials = list(mesh.materials)
        face_material = mesh.face_material.copy()
        groups: dict[str, list[int]] = {g: [] for g in GROUPS}
        for mat_id in np.unique(mesh.face_material):
            used = mesh.face_material == mat_id
            present = [g for g in GROUPS if (used & (face_group == g)).any()]
            for k, g in enumerate(present):
                new_id = int(mat_id)
                if k > 0:                              # a private entry sharing the images
                    new_id = len(materials)
                    materials.append(replace(materials[int(mat_id)], name=f"{materials[int(mat_id)].name}#{g}"))
                    face_material[used & (face_group == g)] = new_id
                groups[g].append(new_id)
        variants: dict[str, int] = {}
        by_name = {_short(m.name): i for i, m in enumerate(materials)}
        textures = Path(stage_dir) / "textures" if stage_dir is not None else None
        for name in dict.fromkeys(surfaces):
            if name in by_name:
                variants[name] = by_name[name]
            elif textures is not None and textures.is_dir():
                mat = _load_variant(textures, name)
                if mat is not None:
                    variants[name] = len(materials)
                    materials.append(mat)
        out = RenderMesh(mesh.vertices, mesh.faces, mesh.face_class, mesh.face_instance, face_material, mesh.face_uv,
                         mesh.classes, materials, mesh.instances, mesh.defect_types, mesh.source)
        return out, cls(out, groups, variants)

    def identity(self) -> MaterialLook:
        return MaterialLook(np.arange(self.n, dtype=np.int32), np.ones((self.n, 3), np.float32))

    def look(self, scene_look) -> MaterialLook:
        """The arrays for one frame's :class:`SceneLook`."""
        remap = np.arange(self.n, dtype=np.int32)
        scale = np.ones((self.n, 3), np.float32)
        applied = {"verge": None, "shoulder": None}
        for group, surface in (("verge", scene_look.verge_surface), ("shoulder", scene_look.shoulder_surface)):
            if self.groups[group] and surface in self.variants:
                remap[self.groups[group]] = self.variants[surface]
                applied[group] = surface
        tint = np.asarray(scene_look.road_tint, np.float32)
        road = tint * np.float32(1.0 + WEAR_LIGHTEN * float(scene_look.road_wear))
        scale[self.groups["road"]] = road
        scale[self.groups["shoulder"]] = tint
        applied["road_scale"] = [round(float(x), 4) for x in road]
        if self.potholes:
            scale[self.potholes] *= np.asarray(scene_look.pothole_albedo, np.float32)
            applied["pothole_albedo"] = [round(float(x), 4) for x in scene_look.pothole_albedo]
            if scene_look.pothole_surface != "pothole" and scene_look.pothole_surface in self.variants:
                remap[self.potholes] = self.variants[scene_look.pothole_surface]
                applied["pothole"] = scene_look.pothole_surface
        return MaterialLook(remap, scale, tuple(float(x) for x in scene_look.sky_tint), applied)


def _group(kind: str) -> str:
    if kind in ROAD_KINDS:
        return "road"
    if kind in SHOULDER_KINDS:
        return "shoulder"
    if kind in VERGE_KINDS:
        return "verge"
    return "other"
