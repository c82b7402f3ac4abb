"""Read a composed town stage back into numpy: what renderers, physics backends and planners
consume (they never need to walk USD themselves)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics

from ..errors import RoadtwinError
from .stage import read_mesh


@dataclass
class TownMesh:
    path: str
    kind: str                 # road segment kind ("driving", "sidewalk" ...) or "collision"
    vertices: np.ndarray      # (N,3) world
    faces: np.ndarray         # (M,3)


@dataclass
class TownDefect:
    id: str
    defect_type: str
    attributes: dict
    pieces: list[TownMesh]    # one baked mesh per segment the defect lies on

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        return concat_meshes(self.pieces)


@dataclass
class TownScene:
    name: str
    source: str
    roads: list[TownMesh] = field(default_factory=list)
    defects: list[TownDefect] = field(default_factory=list)
    colliders: list[TownMesh] = field(default_factory=list)
    metadata: dict = field(default_factory=dict)

    def collision_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """All static colliders as one triangle mesh (road with the defects baked in)."""
        if not self.colliders:
            raise RoadtwinError(f"{self.source}: stage has no collision mesh (compose it with roadtwin first)")
        return concat_meshes(self.colliders)

    def defect(self, defect_id: str) -> TownDefect:
        for d in self.defects:
            if d.id == defect_id:
                return d
        raise RoadtwinError(f"{self.source}: no defect {defect_id!r} (known: {', '.join(d.id for d in self.defects[:10])}...)")


def concat_meshes(meshes: list[TownMesh]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, offset = [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + offset)
        offset += len(m.vertices)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def load_town(path: str | Path) -> TownScene:
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception:
        stage = None
    if stage is None or not stage.GetDefaultPrim():
        raise RoadtwinError(f"{path}: not a USD stage with a defaultPrim")
    root = stage.GetDefaultPrim()
    scene = TownScene(root.GetName(), str(path))
    scene.metadata = {a.GetName().split(":", 2)[-1]: a.Get() for a in root.GetAttributes()
                      if a.GetName().startswith(("roadtwin:layout:", "roadtwin:compose:"))}
    defects: dict[str, TownDefect] = {}
    for prim in Usd.PrimRange(root):
        if prim.HasAttribute("roadtwin:defect:type") and prim.IsA(UsdGeom.Xform):
            attrs = {a.GetName().split(":")[-1]: a.Get() for a in prim.GetAttributes()
                     if a.GetName().startswith("roadtwin:defect:")}
            defects[str(prim.GetPath())] = TownDefect(prim.GetName(), str(attrs.get("type")), attrs, [])
            continue
        if not prim.IsA(UsdGeom.Mesh):
            continue
        v, f = read_mesh(UsdGeom.Mesh(prim))
        if prim.HasAPI(UsdPhysics.CollisionAPI):
            scene.colliders.append(TownMesh(str(prim.GetPath()), "collision", v, f))
        elif prim.HasAttribute("roadtwin:segment:kind"):
            scene.roads.append(TownMesh(str(prim.GetPath()), str(prim.GetAttribute("roadtwin:segment:kind").Get()), v, f))
        elif str(prim.GetParent().GetPath()) in defects:
            d = defects[str(prim.GetParent().GetPath())]
            d.pieces.append(TownMesh(str(prim.GetPath()), d.defect_type, v, f))
    scene.defects = list(defects.values())
    return scene
