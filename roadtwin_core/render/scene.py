"""What a renderer draws: one labelled, textured triangle soup built from a composed town, plus lanes.

``RenderMesh`` is plain numpy (world vertices, faces, and per face: semantic class id, instance
id, material id and the texture coordinates of its three corners, plus a material table of
images), so renderers and benchmarks need no USD. It is built from a
:class:`roadtwin_core.usd.TownScene` (or anything with the same ``roads`` / ``defects`` /
``markings`` attributes, e.g. one made by hand in a test) and can be saved to / loaded from
``.npz``.

Appearance is data: each mesh's material is the ``UsdPreviewSurface`` bound to it in the stage
(``load_town(..., looks=True)``), turned into images here: diffuse in *linear* colour (sRGB
textures decoded), roughness, and a tangent-space normal map; a constant input becomes a 1x1
image, so a renderer samples every material the same way. A mesh with no bound material gets
``DEFAULT_MATERIAL``: neutral 18 % grey, roughness 0.5, no normal map.

Class map (stable across towns with the same plugins): ``background`` (no town geometry: sky
and whatever lies off the road model), the standard road kinds, ``lane_marking``, then every
defect type (sorted), then any other road kind the town uses (sorted), then the labels of the
town's props (``layers/props.usda``: vegetation, pole, sign, vehicle, terrain ...; sorted, only
those it has, so a town without props keeps every id). Semantic annotations are uint8 class ids;
255 is the ignore index (geometry beyond the label range).

Props are drawn like any surface (they occlude defects and cast shadows), with instance id 0; the
:class:`GroundSampler` that puts cameras on the road leaves them out.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..errors import RoadtwinError
from ..geometry import MeshHeights
from ..town.prop_shapes import PROP_LABELS
from .cameras import Lane

BASE_CLASSES = ("background", "driving", "junction", "sidewalk", "shoulder", "lane_marking")
MARKING_CLASS = "lane_marking"
IGNORE_INDEX = 255
WRAP_MODES = ("repeat", "clamp", "mirror")


def class_names(defect_types: Iterable[str] = (), road_kinds: Iterable[str] = (),
                prop_labels: Iterable[str] = ()) -> list[str]:
    """Base classes, defect types (sorted), other road kinds (sorted), then the props' labels
    (sorted; only those the town has, so a town without props keeps its ids)."""
    names = list(BASE_CLASSES)
    for group in (defect_types, road_kinds, prop_labels):
        for t in sorted(set(group)):
            if t not in names:
                names.append(t)
    if len(names) > IGNORE_INDEX:
        raise RoadtwinError(f"{len(names)} semantic classes do not fit uint8 annotations (255 is the ignore index)")
    return names


@dataclass
class RenderMaterial:
    """A material as images a kernel samples: ``diffuse`` (H, W, 3) linear albedo, ``roughness``
    (H, W, 1), ``normal`` (H, W, 3) tangent-space unit-ish vectors or None (flat). Texture
    coordinates repeat / clamp / mirror per ``wrap`` (s, t); a constant is a 1x1 image."""

    name: str
    diffuse: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray | None = None
    metallic: float = 0.0
    wrap: tuple[str, str] = ("repeat", "repeat")

    def __post_init__(self) -> None:
        self.diffuse = _image(self.diffuse, 3, f"material {self.name}: diffuse")
        self.roughness = _image(self.roughness, 1, f"material {self.name}: roughness")
        if self.normal is not None:
            self.normal = _image(self.normal, 3, f"material {self.name}: normal")
        self.wrap = tuple(w if w in WRAP_MODES else "repeat" for w in self.wrap)

    @classmethod
    def constant(cls, name: str, rgb, roughness: float = 0.5, metallic: float = 0.0) -> "RenderMaterial":
        return cls(name, np.asarray(rgb, np.float32).reshape(1, 1, 3), np.full((1, 1, 1), roughness, np.float32),
                   None, metallic)

    def as_dict(self) -> dict:
        """What ``raycast.RaycastScene`` takes (plain numpy, no roadtwin types)."""
        return {"name": self.name, "diffuse": self.diffuse, "roughness": self.roughness, "normal": self.normal,
                "metallic": float(self.metallic), "wrap": tuple(self.wrap)}


def _image(a, channels: int, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1 or a.shape[2] not in (1, channels):
        raise RoadtwinError(f"{what}: expected an image of shape (H, W, {channels}), got {a.shape}")
    if a.shape[2] != channels:
        a = np.repeat(a, channels, axis=2)
    if not np.isfinite(a).all():
        raise RoadtwinError(f"{what}: image has NaN or inf values")
    return np.ascontiguousarray(a)


DEFAULT_MATERIAL = RenderMaterial.constant("default_grey", (0.18, 0.18, 0.18), roughness=0.5)


@dataclass
class RenderMesh:
    vertices: np.ndarray                 # (N,3) float64 world
    faces: np.ndarray                    # (M,3) int64
    face_class: np.ndarray               # (M,) int32 index into classes
    face_instance: np.ndarray            # (M,) int32, 0 = not a defect, k = instances[k-1]
    face_material: np.ndarray            # (M,) int32 index into materials
    face_uv: np.ndarray                  # (M,3,2) float32 texture coordinates (st) per face corner
    classes: list[str]
    materials: list[RenderMaterial] = field(default_factory=lambda: [DEFAULT_MATERIAL])
    instances: list[dict] = field(default_factory=list)   # {"id", "defect_id", "type", "class_id", "attributes"}
    defect_types: list[str] = field(default_factory=list)  # the classes that are defect types
    source: str = ""

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        m = len(self.faces)
        for name in ("face_class", "face_instance", "face_material"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.int32).reshape(m))
        self.face_uv = np.ascontiguousarray(self.face_uv, dtype=np.float32).reshape(m, 3, 2)
        if m == 0:
            raise RoadtwinError(f"{self.source or 'scene'}: no road or defect triangles to render")
        if not np.isfinite(self.vertices).all():
            raise RoadtwinError(f"{self.source or 'scene'}: vertices contain NaN or inf")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise RoadtwinError(f"{self.source or 'scene'}: face indices out of range")
        if not np.isfinite(self.face_uv).all():
            raise RoadtwinError(f"{self.source or 'scene'}: texture coordinates contain NaN or inf")
        if not self.materials or self.face_material.min() < 0 or self.face_material.max() >= len(self.materials):
            raise RoadtwinError(f"{self.source or 'scene'}: face material ids out of range")

    @property
    def class_ids(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.classes)}

    def save_npz(self, path: str | Path, **extra: np.ndarray) -> None:
        """Triangles, labels, st and the material images (``mat<k>_diffuse`` ...); the material
        table's scalars go into the JSON ``info`` (``materials``: name, metallic, wrap, normal)."""
        mats, images = [], {}
        for k, m in enumerate(self.materials):
            mats.append({"name": m.name, "metallic": float(m.metallic), "wrap": list(m.wrap),
                         "normal": m.normal is not None})
            images[f"mat{k}_diffuse"] = m.diffuse
            images[f"mat{k}_roughness"] = m.roughness
            if m.normal is not None:
                images[f"mat{k}_normal"] = m.normal
        info = json.dumps({"classes": self.classes, "instances": self.instances, "source": self.source,
                           "defect_types": self.defect_types, "materials": mats})
        np.savez_compressed(path, vertices=self.vertices.astype(np.float32), faces=self.faces.astype(np.int32),
                            face_class=self.face_class, face_instance=self.face_instance,
                            face_material=self.face_material, face_uv=self.face_uv,
                            info=np.frombuffer(info.encode(), dtype=np.uint8), **images, **extra)

    @classmethod
    def load_npz(cls, path: str | Path) -> "RenderMesh":
        with np.load(path) as z:
            info = json.loads(bytes(z["info"]).decode())
            mats = [RenderMaterial(m["name"], z[f"mat{k}_diffuse"], z[f"mat{k}_roughness"],
                                   z[f"mat{k}_normal"] if m["normal"] else None, m["metallic"], tuple(m["wrap"]))
                    for k, m in enumerate(info["materials"])]
            return cls(z["vertices"], z["faces"], z["face_class"], z["face_instance"], z["face_material"],
                       z["face_uv"], info["classes"], mats, info["instances"], info.get("defect_types", []),
                       info.get("source", ""))


def _jsonable(v):
    if isinstance(v, (str, bool, int, float)) or v is None:
        return v
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    try:
        return [_jsonable(x) for x in v]
    except TypeError:
        return str(v)


def render_material(mat) -> RenderMaterial:
    """A stage material (:class:`roadtwin_core.usd.looks_reader.TownMaterial`) as images."""
    from ..usd.looks_reader import decode_texture   # roadtwin_core.usd imports pxr; GPU machines have no USD

    if mat.diffuse_texture is not None:
        diffuse = decode_texture(mat.diffuse_texture)
    else:
        diffuse = np.asarray(mat.diffuse_color, np.float32).reshape(1, 1, 3)
    if mat.roughness_texture is not None:
        rough = decode_texture(mat.roughness_texture)
    else:
        rough = np.full((1, 1, 1), mat.roughness, np.float32)
    normal = decode_texture(mat.normal_texture) if mat.normal_texture is not None else None
    first = next((t for t in (mat.diffuse_texture, mat.roughness_texture, mat.normal_texture) if t is not None), None)
    wrap = (first.wrap_s, first.wrap_t) if first is not None else ("repeat", "repeat")
    return RenderMaterial(mat.name, np.clip(diffuse, 0.0, None), np.clip(rough, 0.0, 1.0), normal,
                          mat.metallic, wrap)


def build_render_mesh(town, defect_types: Iterable[str] = ()) -> RenderMesh:
    """One labelled, textured mesh from a town's road meshes, baked defect pieces and lane
    markings. Materials are the stage's bindings (read with ``load_town(..., looks=True)``);
    meshes without one get ``DEFAULT_MATERIAL``, meshes without st get st = 0."""
    source = getattr(town, "source", "")
    kinds = [m.kind for m in town.roads]
    dtypes = sorted(set(defect_types) | {d.defect_type for d in town.defects})
    props = list(getattr(town, "props", ()))
    classes = class_names(dtypes, kinds, [m.kind for m in props])
    cid = {n: i for i, n in enumerate(classes)}
    verts, faces, fclass, finst, fmat, fuv = [], [], [], [], [], []
    materials: list[RenderMaterial] = [DEFAULT_MATERIAL]
    mat_index: dict[str, int] = {}
    offset = 0

    def material_id(mesh) -> int:
        mat = getattr(mesh, "material", None)
        if mat is None:
            return 0
        if mat.name not in mat_index:
            mat_index[mat.name] = len(materials)
            materials.append(render_material(mat))
        return mat_index[mat.name]

    def add(mesh, c, inst):
        nonlocal offset
        v = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
        st = getattr(mesh, "st", None)
        st = np.zeros((len(f), 3, 2), np.float32) if st is None else np.asarray(st, np.float32).reshape(len(f), 3, 2)
        verts.append(v)
        faces.append(f + offset)
        fuv.append(st)
        offset += len(v)
        for lst, val in ((fclass, c), (finst, inst), (fmat, material_id(mesh))):
            lst.append(np.full(len(f), val, dtype=np.int32))

    for m in town.roads:
        add(m, cid[m.kind], 0)
    instances = []
    for k, d in enumerate(town.defects, start=1):
        instances.append({"id": k, "defect_id": d.id, "type": d.defect_type, "class_id": cid[d.defect_type],
                          "attributes": {a: _jsonable(v) for a, v in sorted(d.attributes.items())}})
        for piece in d.pieces:
            add(piece, cid[d.defect_type], k)
    for m in getattr(town, "markings", ()):
        add(m, cid[MARKING_CLASS], 0)
    # props last: they occlude and shadow the road like any surface; instance 0 (not a defect)
    for m in props:
        add(m, cid[m.kind], 0)
    if not faces:
        raise RoadtwinError(f"{source or 'town'}: no road or defect meshes to render")
    return RenderMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(fclass), np.concatenate(finst),
                      np.concatenate(fmat), np.concatenate(fuv), classes, materials, instances,
                      [c for c in classes if c in dtypes], source)


PROP_CLASSES = (*PROP_LABELS, "prop")   # the props' labels; "prop": an instancer's unlabelled prototype


class GroundSampler(MeshHeights):
    """Height of the road under XY points, for placing cameras a fixed height above it
    (:class:`~roadtwin_core.geometry.MeshHeights` of a render mesh on a 2 m grid). Props (a
    parked car, a tree's crown over the lane) are not the road: their faces are left out."""

    def __init__(self, mesh: RenderMesh, cell_m: float = 2.0):
        faces = mesh.faces
        classes = getattr(mesh, "classes", None)     # apps/compose/preview.py passes bare vertices and faces
        if classes is not None and getattr(mesh, "face_class", None) is not None:
            is_prop = np.array([c in PROP_CLASSES for c in classes], dtype=bool)
            faces = faces[~is_prop[mesh.face_class]]
        super().__init__(mesh.vertices, faces, cell_m)


def stage_lanes(stage_path: str | Path, kinds: Sequence[str] = ("driving",)) -> list[Lane]:
    """Lane centerlines (``roadtwin:segment:centerline``, travel order) of the segments of the
    given kinds in a composed town stage (they come from the layout sublayer)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(stage_path))
    if stage is None:
        raise RoadtwinError(f"{stage_path}: not a USD stage")
    lanes = []
    for prim in stage.Traverse():
        kind = prim.GetAttribute("roadtwin:segment:kind")
        line = prim.GetAttribute("roadtwin:segment:centerline")
        if not (kind and line and line.HasAuthoredValue()) or str(kind.Get()) not in kinds:
            continue
        pts = np.asarray(line.Get(), dtype=np.float64).reshape(-1, 2)
        if len(pts) >= 2:
            lanes.append(Lane(prim.GetName(), pts))
    return lanes
