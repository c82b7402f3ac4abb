"""Write a composed town: root ``town.usda`` sublayering one layer per concern.

Strongest first: looks, semantics, physics, markings, defects, roads, then the untouched input
layout (copied into ``layout/``). Roads *override* the layout's planar segment meshes with the merged, elevated
road surface, so muting ``roads.usda`` shows the input again. Defect instances carry their baked
geometry (each one drapes over a different piece of road, so it cannot be shared). The physics
layer applies static triangle-mesh collision (``CollisionAPI`` + ``MeshCollisionAPI``,
approximation none) as overs to those same road and defect meshes: together they are the road
with the defects baked in, and what collides is exactly what is drawn (no copy to drift). Lane
markings are draped paint meshes under ``/<root>/MarkingMeshes``: ``/<root>/Markings`` already
holds the layout's marking curves (guide-purpose BasisCurves, the input data), and a mesh over
the same path would inherit the curve's attributes and purpose. The looks layer holds the materials and binds
them (see ``looks.py``). Every rendered mesh carries ``primvars:st`` (the st convention of
:mod:`roadtwin_core.looks`): lane-aligned on driving segments with a centreline, world-planar
elsewhere.

Each mesh is stored once, and in binary: ``roads``, ``defects`` and ``markings`` each sublayer a
crate ``layers/<name>.geom.usdc`` holding their meshes' arrays (points, face counts and indices,
extent, st), authored at the Sdf level straight from numpy; the ``.usda`` layers keep what a
person reads (prims, kinds, attributes). A sublayer rather than a reference or payload, because
the road segments are defined in the input layout, a local opinion that LIVRPS ranks above any
reference: a referenced crate's points would lose to the layout's planar ones.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdPhysics

from ..looks.catalog import ROAD_MATERIAL_VARIANTS, MaterialSpec, defect_material, kind_material, marking_material
from ..markings import MarkingMesh
from ..model import MergedSegment, Placement, RoadSegment, TownLayout
from .looks import write_looks
from .stage import (author_api_over, author_labels, author_mesh_geometry, lane_st, new_layer, new_stage, planar_st, safe_prim_name,
                    set_attrs, set_kind)

LAYERS = ("looks", "semantics", "physics", "markings", "defects", "roads")
VARIANT_KINDS = ("driving", "junction")  # the surfaces the root's roadMaterial variant set switches
DEFAULT_ROAD_MATERIAL = "asphalt"
GEOMETRY_SUFFIX = ".geom.usdc"  # layers/<name>.usda sublayers layers/<name>.geom.usdc
MARKING_MESHES = "MarkingMeshes"  # group of the draped paint meshes (the layout's curves are in "Markings")


@dataclass
class TownParts:
    layout: TownLayout
    layout_file: str                      # path of the copied layout, relative to town.usda
    merged: list[MergedSegment]           # one per layout segment, same order
    owners: list[list[int]]               # per segment: merger owner index -> placement index
    placements: list[Placement]
    library_files: dict[str, str]         # model name -> asset path relative to town.usda
    compose_info: dict
    markings: list[MarkingMesh] = field(default_factory=list)
    materials: dict[str, MaterialSpec] = field(default_factory=dict)  # name -> spec (textures/ beside town.usda)


def segment_st(seg: RoadSegment, vertices: np.ndarray) -> np.ndarray:
    """Lane-aligned st on driving segments with a centreline, world-planar elsewhere."""
    if seg.kind == "driving" and seg.centerline is not None and len(seg.centerline) >= 2:
        return lane_st(vertices, seg.centerline)
    return planar_st(vertices)


def marking_prim_names(markings: list[MarkingMesh]) -> list[str]:
    """Safe, unique prim names for the markings (ids may repeat or clash once sanitised)."""
    names, seen = [], set()
    for m in markings:
        base = name = safe_prim_name(m.id)
        k = 1
        while name in seen:
            name, k = f"{base}_{k}", k + 1
        seen.add(name)
        names.append(name)
    return names


def road_variants(segments: list[RoadSegment]) -> dict[str, list[tuple[str, str]]]:
    """``roadMaterial`` variant -> bindings of the driving and junction surfaces. The default
    variant keeps the catalog's per-kind look (worn lanes, newer junctions); the others pave
    both with the variant's material."""
    out = {}
    for variant, material in ROAD_MATERIAL_VARIANTS.items():
        out[variant] = [(seg.prim_path, kind_material(seg.kind) if variant == DEFAULT_ROAD_MATERIAL else material)
                        for seg in segments if seg.kind in VARIANT_KINDS]
    return out


def _write_markings(outdir: Path, name: str, doc: str, markings: list[MarkingMesh], prim_names: list[str]) -> None:
    """``/<root>/MarkingMeshes/<id>`` meshes (kind component under a group), type and colour as
    token attributes (as on the layout's curves); their arrays go to ``markings.geom.usdc``."""
    root = f"/{name}"
    stage = new_stage(outdir / "layers/markings.usda", name, doc + ": lane markings draped on the road")
    _over(stage, root)
    geometry = _geometry_layer(outdir, "markings", name, doc)
    with Sdf.ChangeBlock():
        for prim_name, m in zip(prim_names, markings):
            author_mesh_geometry(geometry, f"{root}/{MARKING_MESHES}/{prim_name}", m.vertices, m.faces,
                                 planar_st(m.vertices))
    if markings:
        set_kind(UsdGeom.Xform.Define(stage, f"{root}/{MARKING_MESHES}").GetPrim(), "group")
    for prim_name, m in zip(prim_names, markings):
        mesh = UsdGeom.Mesh.Define(stage, f"{root}/{MARKING_MESHES}/{prim_name}")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        prim = mesh.GetPrim()
        set_kind(prim, "component")
        for key, value in (("type", m.marking_type), ("color", m.color)):
            prim.CreateAttribute(f"roadtwin:marking:{key}", Sdf.ValueTypeNames.Token, custom=True).Set(value)
        prim.CreateAttribute("roadtwin:marking:id", Sdf.ValueTypeNames.String, custom=True).Set(m.id)
    _save(stage, geometry)


def _over(stage: Usd.Stage, path: str) -> Usd.Prim:
    return stage.OverridePrim(Sdf.Path(path))


def _geometry_layer(outdir: Path, layer: str, name: str, doc: str) -> Sdf.Layer:
    """The crate beside ``layers/<layer>.usda`` that holds its meshes' arrays."""
    return new_layer(outdir / "layers" / f"{layer}{GEOMETRY_SUFFIX}", name,
                     f"{doc}: mesh arrays of {layer}.usda (crate, sublayered by it)")


def _save(stage: Usd.Stage, geometry: Sdf.Layer) -> None:
    """Save the crate, then the readable layer sublayering it (added last, so the stage composes
    the crate once instead of after every edit)."""
    geometry.Save()
    layer = stage.GetRootLayer()
    layer.subLayerPaths.append(f"./{Path(geometry.realPath).name}")
    layer.Save()


def write_town(outdir: Path, parts: TownParts) -> Path:
    lay = parts.layout
    root = f"/{lay.name}"
    (outdir / "layers").mkdir(exist_ok=True)
    doc = f"roadtwin town composed from {Path(lay.source).name}"

    roads = new_stage(outdir / "layers/roads.usda", lay.name, doc + ": merged road surfaces")
    _over(roads, root)
    geometry = _geometry_layer(outdir, "roads", lay.name, doc)
    with Sdf.ChangeBlock():
        for seg, m in zip(lay.segments, parts.merged):
            v, f = m.part(-1)
            author_mesh_geometry(geometry, seg.prim_path, v, f, segment_st(seg, v))
    for seg in lay.segments:
        UsdGeom.Mesh(_over(roads, seg.prim_path)).CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    _save(roads, geometry)

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
    geometry = _geometry_layer(outdir, "defects", lay.name, doc)
    with Sdf.ChangeBlock():
        for i, p in enumerate(parts.placements):
            for seg_id, v, f in pieces.get(i, []):
                author_mesh_geometry(geometry, f"{root}/Defects/{p.instance_id}/{seg_id}", v, f, planar_st(v))
    for i, p in enumerate(parts.placements):
        prim = UsdGeom.Xform.Define(defects, f"{root}/Defects/{p.instance_id}").GetPrim()
        set_kind(prim, "component")
        attrs = p.attributes()
        set_attrs(prim, "roadtwin:defect", {k: attrs[k] for k in ("type", "depthM", "heightM", "areaM2", "volumeM3")})
        set_attrs(prim, "roadtwin:defect", {"model": attrs["model"], "segments": list(p.segment_ids),
                                            "poseXYYaw": [p.x, p.y, p.yaw], "scale": list(p.scale)})
        prim.CreateAttribute("roadtwin:source", Sdf.ValueTypeNames.Asset, custom=True).Set(
            Sdf.AssetPath("../" + parts.library_files[p.model.name].removeprefix("./")))  # relative to layers/
        for seg_id, _, _ in pieces.get(i, []):
            mesh = UsdGeom.Mesh.Define(defects, f"{root}/Defects/{p.instance_id}/{seg_id}")
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    _save(defects, geometry)

    marking_names = marking_prim_names(parts.markings)
    _write_markings(outdir, lay.name, doc, parts.markings, marking_names)

    physics = new_stage(outdir / "layers/physics.usda", lay.name, doc + ": static road collision")
    _over(physics, root)
    scene = UsdPhysics.Scene.Define(physics, f"{root}/PhysicsScene")
    scene.CreateGravityDirectionAttr((0.0, 0.0, -1.0))
    scene.CreateGravityMagnitudeAttr(9.81)
    colliders = [seg.prim_path for seg in lay.segments]
    colliders += [f"{root}/Defects/{p.instance_id}/{seg_id}" for i, p in enumerate(parts.placements)
                  for seg_id, _, _ in pieces.get(i, [])]
    with Sdf.ChangeBlock():
        for path in colliders:
            author_api_over(physics.GetRootLayer(), path, ["PhysicsCollisionAPI", "PhysicsMeshCollisionAPI"],
                            {"physics:approximation": (Sdf.ValueTypeNames.Token, UsdPhysics.Tokens.none)}, uniform=True)
    physics.GetRootLayer().Save()

    sem = new_stage(outdir / "layers/semantics.usda", lay.name, doc + ": semantic labels")
    _over(sem, root)
    labels = [(seg.prim_path, ["road", seg.kind]) for seg in lay.segments]
    labels += [(f"{root}/Defects/{p.instance_id}", ["road_defect", p.model.defect_type]) for p in parts.placements]
    labels += [(f"{root}/{MARKING_MESHES}/{name}", ["lane_marking", m.marking_type])
               for name, m in zip(marking_names, parts.markings)]
    with Sdf.ChangeBlock():
        for path, tags in labels:
            author_labels(sem.GetRootLayer(), path, tags)
    sem.GetRootLayer().Save()

    looks = new_stage(outdir / "layers/looks.usda", lay.name, doc + ": materials and their bindings")
    _over(looks, root)
    bindings = [(seg.prim_path, kind_material(seg.kind)) for seg in lay.segments if seg.kind not in VARIANT_KINDS]
    for i, p in enumerate(parts.placements):
        material = defect_material(p.model.defect_type)
        bindings += [(f"{root}/Defects/{p.instance_id}/{seg_id}", material) for seg_id, _, _ in pieces.get(i, [])]
    bindings += [(f"{root}/{MARKING_MESHES}/{name}", marking_material(m.color)) for name, m in zip(marking_names, parts.markings)]
    write_looks(looks, root, parts.materials, bindings, road_variants(lay.segments), DEFAULT_ROAD_MATERIAL)
    looks.GetRootLayer().Save()

    town_path = outdir / "town.usda"
    town = new_stage(town_path, lay.name, doc)
    town.GetRootLayer().subLayerPaths = [f"./layers/{n}.usda" for n in LAYERS] + [f"./{parts.layout_file}"]
    top = _over(town, root)
    set_kind(top, "assembly")
    set_attrs(top, "roadtwin:compose", parts.compose_info)
    town.GetRootLayer().Save()
    return town_path
