"""What a renderer draws: one labelled triangle soup built from a composed town, plus lanes.

``RenderMesh`` is plain numpy (world vertices, faces, and per face: semantic class id, instance
id, material id, tint), so renderers and benchmarks need no USD. It is built from a
:class:`roadtwin_core.usd.TownScene` (or anything with the same ``roads`` / ``defects``
attributes, e.g. one made by hand in a test) and can be saved to / loaded from ``.npz``.

Class map (stable across towns with the same plugins): ``background`` (no town geometry: sky
and whatever lies off the road model), the standard road kinds, then every defect type (sorted),
then any other road kind the town uses (sorted). Semantic annotations are uint8 class ids; 255
is the ignore index (geometry beyond the label range).
"""
from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..errors import RoadtwinError
from .cameras import Lane

BASE_CLASSES = ("background", "driving", "junction", "sidewalk", "shoulder")
IGNORE_INDEX = 255
MATERIALS = ("asphalt", "cobblestone", "cement")
MATERIAL_RULES = ("kind", "random") + MATERIALS
_KIND_MATERIAL = {"driving": "asphalt", "junction": "cobblestone", "sidewalk": "cement", "shoulder": "asphalt"}


def class_names(defect_types: Iterable[str] = (), road_kinds: Iterable[str] = ()) -> list[str]:
    names = list(BASE_CLASSES)
    for t in sorted(set(defect_types)):
        if t not in names:
            names.append(t)
    for k in sorted(set(road_kinds)):
        if k not in names:
            names.append(k)
    if len(names) > IGNORE_INDEX:
        raise RoadtwinError(f"{len(names)} semantic classes do not fit uint8 annotations (255 is the ignore index)")
    return names


@dataclass
class RenderMesh:
    vertices: np.ndarray                 # (N,3) float64 world
    faces: np.ndarray                    # (M,3) int64
    face_class: np.ndarray               # (M,) int32 index into classes
    face_instance: np.ndarray            # (M,) int32, 0 = not a defect, k = instances[k-1]
    face_material: np.ndarray            # (M,) int32 index into MATERIALS
    face_tint: np.ndarray                # (M,) float32 in [0,1): per-segment variation
    classes: list[str]
    instances: list[dict] = field(default_factory=list)   # {"id", "defect_id", "type", "class_id", "attributes"}
    defect_types: list[str] = field(default_factory=list)  # the classes that are defect types
    source: str = ""

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        m = len(self.faces)
        for name in ("face_class", "face_instance", "face_material"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.int32).reshape(m))
        self.face_tint = np.ascontiguousarray(self.face_tint, dtype=np.float32).reshape(m)
        if m == 0:
            raise RoadtwinError(f"{self.source or 'scene'}: no road or defect triangles to render")
        if not np.isfinite(self.vertices).all():
            raise RoadtwinError(f"{self.source or 'scene'}: vertices contain NaN or inf")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise RoadtwinError(f"{self.source or 'scene'}: face indices out of range")

    @property
    def class_ids(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.classes)}

    def save_npz(self, path: str | Path, **extra: np.ndarray) -> None:
        info = json.dumps({"classes": self.classes, "instances": self.instances, "source": self.source,
                           "defect_types": self.defect_types,
                           "materials": list(MATERIALS)})
        np.savez_compressed(path, vertices=self.vertices.astype(np.float32), faces=self.faces.astype(np.int32),
                            face_class=self.face_class, face_instance=self.face_instance,
                            face_material=self.face_material, face_tint=self.face_tint,
                            info=np.frombuffer(info.encode(), dtype=np.uint8), **extra)

    @classmethod
    def load_npz(cls, path: str | Path) -> "RenderMesh":
        with np.load(path) as z:
            info = json.loads(bytes(z["info"]).decode())
            return cls(z["vertices"], z["faces"], z["face_class"], z["face_instance"], z["face_material"],
                       z["face_tint"], info["classes"], info["instances"], info.get("defect_types", []),
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


def _segment_tint(seed: int, name: str) -> float:
    return float(np.random.default_rng([seed, zlib.crc32(name.encode())]).random())


def _material_for(rule: str, kind: str, seed: int, name: str) -> int:
    if kind == "sidewalk":
        return MATERIALS.index("cement")
    if rule == "kind":
        return MATERIALS.index(_KIND_MATERIAL.get(kind, "asphalt"))
    if rule == "random":
        rng = np.random.default_rng([seed, zlib.crc32(name.encode()), 1])
        return int(rng.choice(len(MATERIALS), p=[0.6, 0.2, 0.2]))
    return MATERIALS.index(rule)


def build_render_mesh(town, defect_types: Iterable[str] = (), material: str = "kind", seed: int = 0) -> RenderMesh:
    """One labelled mesh from a town's road meshes and baked defect pieces.

    ``material``: ``kind`` (driving asphalt, junction cobblestone, sidewalk cement), ``random``
    (a seeded choice per segment, sidewalks stay cement) or one material for every road.
    A defect piece takes the material of the segment it lies on (its prim name), so a pothole in
    a cobblestone junction shows cobblestone, darkened.
    """
    if material not in MATERIAL_RULES:
        raise RoadtwinError(f"unknown material rule {material!r} (known: {', '.join(MATERIAL_RULES)})")
    source = getattr(town, "source", "")
    kinds = [m.kind for m in town.roads]
    dtypes = sorted(set(defect_types) | {d.defect_type for d in town.defects})
    classes = class_names(dtypes, kinds)
    cid = {n: i for i, n in enumerate(classes)}
    verts, faces, fclass, finst, fmat, ftint = [], [], [], [], [], []
    offset = 0
    seg_material: dict[str, tuple[int, float]] = {}

    def add(v, f, c, inst, mat, tint):
        nonlocal offset
        v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
        for lst, val, dt in ((fclass, c, np.int32), (finst, inst, np.int32), (fmat, mat, np.int32),
                             (ftint, tint, np.float32)):
            lst.append(np.full(len(f), val, dtype=dt))

    for m in town.roads:
        name = m.path.rsplit("/", 1)[-1]
        mat, tint = _material_for(material, m.kind, seed, name), _segment_tint(seed, name)
        seg_material[name] = (mat, tint)
        add(m.vertices, m.faces, cid[m.kind], 0, mat, tint)
    instances = []
    for k, d in enumerate(town.defects, start=1):
        instances.append({"id": k, "defect_id": d.id, "type": d.defect_type, "class_id": cid[d.defect_type],
                          "attributes": {a: _jsonable(v) for a, v in sorted(d.attributes.items())}})
        for piece in d.pieces:
            seg = piece.path.rsplit("/", 1)[-1]
            mat, tint = seg_material.get(seg, (MATERIALS.index("asphalt"), 0.5))
            add(piece.vertices, piece.faces, cid[d.defect_type], k, mat, tint)
    if not faces:
        raise RoadtwinError(f"{source or 'town'}: no road or defect meshes to render")
    return RenderMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(fclass), np.concatenate(finst),
                      np.concatenate(fmat), np.concatenate(ftint), classes, instances,
                      [c for c in classes if c in dtypes], source)


class GroundSampler:
    """Height of the topmost triangle under XY points (NaN off the mesh), for placing cameras a
    fixed height above the road. An STRtree over the triangles' XY outlines, then barycentric z."""

    def __init__(self, mesh: RenderMesh):
        import shapely

        tri = mesh.vertices[mesh.faces]
        area = 0.5 * np.abs((tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1])
                            - (tri[:, 1, 1] - tri[:, 0, 1]) * (tri[:, 2, 0] - tri[:, 0, 0]))
        self.tri = tri[area > 1e-12]
        self.tree = shapely.STRtree(shapely.polygons(self.tri[:, :, :2]))

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        import shapely

        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        out = np.full(len(xy), np.nan)
        if not len(xy):
            return out
        pi, ti = self.tree.query(shapely.points(xy), predicate="intersects")
        if not len(pi):
            return out
        a, b, c = self.tri[ti, 0], self.tri[ti, 1], self.tri[ti, 2]
        p = xy[pi]
        v0, v1, v2 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2], p - a[:, :2]
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        beta = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
        gamma = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
        z = a[:, 2] + beta * (b[:, 2] - a[:, 2]) + gamma * (c[:, 2] - a[:, 2])
        np.fmax.at(out, pi, z)
        return out


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
