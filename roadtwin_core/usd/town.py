"""Write a composed town: root ``town.usda`` sublayering one layer per concern.

Strongest first: semantics, physics, defects, roads, then the untouched input layout (copied
into ``layout/``). Roads *override* the layout's planar segment meshes with the merged, elevated
road surface, so muting ``roads.usda`` shows the input again. Defect instances carry their baked
geometry (each one drapes over a different piece of road, so it cannot be shared). The physics
layer holds one static triangle-mesh collider per segment with the defects baked in.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdPhysics

from ..model import MergedSegment, Placement, TownLayout
from .stage import apply_labels, new_stage, set_attrs, set_kind, write_mesh

LAYERS = ("semantics", "physics", "defects", "roads")


@dataclass
class TownParts:
    layout: TownLayout
    layout_file: str                      # path of the copied layout, relative to town.usda
    merged: list[MergedSegment]           # one per layout segment, same order
    owners: list[list[int]]               # per segment: merger owner index -> placement index
    placements: list[Placement]
    library_files: dict[str, str]         # model name -> asset path relative to town.usda
    compose_info: dict


def _over(stage: Usd.Stage, path: str) -> Usd.Prim:
    return stage.OverridePrim(Sdf.Path(path))


def write_town(outdir: Path, parts: TownParts) -> Path:
    lay = parts.layout
    root = f"/{lay.name}"
    (outdir / "layers").mkdir(exist_ok=True)
    doc = f"roadtwin town composed from {Path(lay.source).name}"

    roads = new_stage(outdir / "layers/roads.usda", lay.name, doc + ": merged road surfaces")
    _over(roads, root)
    for seg, m in zip(lay.segments, parts.merged):
        v, f = m.part(-1)
        mesh = UsdGeom.Mesh(_over(roads, seg.prim_path))
        write_mesh(mesh, v, f)
    roads.GetRootLayer().Save()

    defects = new_stage(outdir / "layers/defects.usda", lay.name, doc + ": defect instances")
    _over(defects, root)
    group = UsdGeom.Xform.Define(defects, f"{root}/Defects").GetPrim()
    set_kind(group, "group")
    pieces: dict[int, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    for seg, m, own in zip(lay.segments, parts.merged, parts.owners):
        for local, global_index in enumerate(own):
            if (m.face_owner == local).any():
                v, f = m.part(local)
                pieces.setdefault(global_index, []).append((seg.id, v, f))
    for i, p in enumerate(parts.placements):
        prim = UsdGeom.Xform.Define(defects, f"{root}/Defects/{p.instance_id}").GetPrim()
        set_kind(prim, "component")
        attrs = p.attributes()
        set_attrs(prim, "roadtwin:defect", {k: attrs[k] for k in ("type", "depthM", "heightM", "areaM2", "volumeM3")})
        set_attrs(prim, "roadtwin:defect", {"model": attrs["model"], "segments": list(p.segment_ids),
                                            "poseXYYaw": [p.x, p.y, p.yaw], "scale": list(p.scale)})
        prim.CreateAttribute("roadtwin:source", Sdf.ValueTypeNames.Asset, custom=True).Set(
            Sdf.AssetPath("../" + parts.library_files[p.model.name].removeprefix("./")))  # relative to layers/
        for seg_id, v, f in pieces.get(i, []):
            write_mesh(UsdGeom.Mesh.Define(defects, f"{root}/Defects/{p.instance_id}/{seg_id}"), v, f)
    defects.GetRootLayer().Save()

    physics = new_stage(outdir / "layers/physics.usda", lay.name, doc + ": static road collision")
    _over(physics, root)
    scene = UsdPhysics.Scene.Define(physics, f"{root}/PhysicsScene")
    scene.CreateGravityDirectionAttr((0.0, 0.0, -1.0))
    scene.CreateGravityMagnitudeAttr(9.81)
    col = UsdGeom.Xform.Define(physics, f"{root}/Collision").GetPrim()
    set_kind(col, "group")
    for seg, m in zip(lay.segments, parts.merged):
        mesh = UsdGeom.Mesh.Define(physics, f"{root}/Collision/{seg.id}")
        write_mesh(mesh, m.vertices, m.faces)
        mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
        UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.none)
    physics.GetRootLayer().Save()

    sem = new_stage(outdir / "layers/semantics.usda", lay.name, doc + ": semantic labels")
    _over(sem, root)
    for seg in lay.segments:
        apply_labels(_over(sem, seg.prim_path), ["road", seg.kind])
        apply_labels(_over(sem, f"{root}/Collision/{seg.id}"), ["road", "collision"])
    for p in parts.placements:
        apply_labels(_over(sem, f"{root}/Defects/{p.instance_id}"), ["road_defect", p.model.defect_type])
    sem.GetRootLayer().Save()

    town_path = outdir / "town.usda"
    town = new_stage(town_path, lay.name, doc)
    town.GetRootLayer().subLayerPaths = [f"./layers/{n}.usda" for n in LAYERS] + [f"./{parts.layout_file}"]
    top = _over(town, root)
    set_kind(top, "assembly")
    set_attrs(top, "roadtwin:compose", parts.compose_info)
    town.GetRootLayer().Save()
    return town_path
