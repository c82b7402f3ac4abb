"""Write a composed town: root ``town.usda`` sublayering one layer per concern.

Strongest first: looks, semantics, physics, props, markings, defects, roads, then the untouched
input layout (copied into ``layout/``). ``props`` (the roadside world: PointInstancers of
procedural trees, poles, signs, vehicles ... and a terrain mesh; :mod:`.props`) is there when
the town has props. Roads *override* the layout's planar segment meshes with the merged, elevated
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
from typing import Callable, Mapping
from pathlib import Path

import numpy as np
from pxr import Sdf, UsdGeom, UsdPhysics

from ..errors import RoadtwinError
from ..looks.catalog import (DEFAULT_DEFECT_MATERIAL, ROAD_MATERIAL_VARIANTS, MaterialSpec, kind_material,
                             marking_material)
from ..town.markings import MarkingMesh
from ..model import MergedSegment, Placement, RoadSegment, TownLayout
from ..town.props import Props
from .library import defect_labels, look_texture_files
from .looks import write_looks
from .props import write_props
from .stage import (GEOMETRY_SUFFIX, author_api_over, author_attrs, author_labels, author_mesh_geometry, author_uniform,
                    define_prim, lane_st, new_layer, planar_st, safe_prim_name)

LAYERS = ("looks", "semantics", "physics", "props", "markings", "defects", "roads")  # props: when the town has them
VARIANT_KINDS = ("driving", "junction")  # the surfaces the root's roadMaterial variant set switches
DEFAULT_ROAD_MATERIAL = "asphalt"
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
    semantic_classes: dict[str, str] = field(default_factory=dict)    # defect type -> class (default road_defect)
    defect_materials: dict[str, str] = field(default_factory=dict)    # defect type -> catalog material (default worn)
    props: Props | None = None            # the roadside world (layers/props.usda); None: no props layer
    road_textures: dict[str, str] = field(default_factory=dict)  # extra roadMaterial variant -> material (in materials)
    road_material: str = DEFAULT_ROAD_MATERIAL  # the roadMaterial variant selected


def defect_material_name(p: Placement, materials: Mapping[str, str]) -> str:
    """The material a defect instance's pieces wear: its model's own texture (a photo-made
    asset: ``decal_<model>``) or the catalog material its type names (``materials``: defect type
    -> material, from each type's ``material``; default worn asphalt)."""
    if p.model.look is not None:
        return f"decal_{p.model.name}"
    return materials.get(p.model.defect_type, DEFAULT_DEFECT_MATERIAL)


def defect_st(p: Placement, vertices: np.ndarray) -> np.ndarray:
    """st of a defect piece's vertices: the model's own texture mapped back through the
    placement (so whichever piece of the footprint the merger made shows its part of the
    texture), else world-planar like the road."""
    if p.model.look is None:
        return planar_st(vertices)
    return p.model.look.st(p.local_xy(np.asarray(vertices)[:, :2]))


def decal_materials(outdir: Path, placements: list[Placement],
                    library_files: dict[str, str]) -> tuple[dict[str, MaterialSpec], dict[str, str]]:
    """One clamped material per textured model placed, over the textures of the town's own copy
    of its library asset (``library/textures/<model>_<role>.png``, :func:`look_texture_files`),
    so the town stores each texture once. Returns the specs and each one's texture folder,
    relative to ``layers/looks.usda`` (``../library/textures``: the town can still move)."""
    specs: dict[str, MaterialSpec] = {}
    folders: dict[str, str] = {}
    models = {p.model.name: p.model for p in placements if p.model.look is not None}
    for name in sorted(models):
        folder = (Path(library_files[name]).parent / "textures").as_posix()
        files = look_texture_files(models[name])
        for file in files.values():
            if not (outdir / folder / file).is_file():
                raise RoadtwinError(f"defect model {name!r}: texture {folder}/{file} is not in the town's library copy")
        specs[f"decal_{name}"] = MaterialSpec(f"decal_{name}", files["diffuse"], files.get("roughness"),
                                              normal=files.get("normal"), wrap="clamp",
                                              doc=f"defect {name}'s own texture (source: {models[name].source})")
        folders[f"decal_{name}"] = f"../{folder}"
    return specs, folders


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


def road_variants(segments: list[RoadSegment], extra: dict[str, str] | None = None) -> dict[str, list[tuple[str, str]]]:
    """``roadMaterial`` variant -> bindings of the driving and junction surfaces. The default
    variant keeps the catalog's per-kind look (worn lanes, newer junctions); the others pave
    both with the variant's material. ``extra``: more variants (name -> material), e.g. the
    surfaces cut from photos that ``compose --road-textures`` brings."""
    out = {}
    for variant, material in {**ROAD_MATERIAL_VARIANTS, **(extra or {})}.items():
        out[variant] = [(seg.prim_path, kind_material(seg.kind) if variant == DEFAULT_ROAD_MATERIAL else material)
                        for seg in segments if seg.kind in VARIANT_KINDS]
    return out


def _write_markings(outdir: Path, name: str, doc: str, markings: list[MarkingMesh], prim_names: list[str]) -> None:
    """``/<root>/MarkingMeshes/<id>`` meshes (kind component under a group), type and colour as
    token attributes (as on the layout's curves); their arrays go to ``markings.geom.usdc``."""
    root = f"/{name}"
    layer = _readable_layer(outdir, "markings", name, doc + ": lane markings draped on the road")
    geometry = _geometry_layer(outdir, "markings", name, doc)
    with Sdf.ChangeBlock():
        for prim_name, m in zip(prim_names, markings):
            author_mesh_geometry(geometry, f"{root}/{MARKING_MESHES}/{prim_name}", m.vertices, m.faces,
                                 planar_st(m.vertices))
        if markings:
            define_prim(layer, f"{root}/{MARKING_MESHES}", "Xform", "group")
        for prim_name, m in zip(prim_names, markings):
            spec = define_prim(layer, f"{root}/{MARKING_MESHES}/{prim_name}", "Mesh", "component")
            _no_subdivision(spec)
            for key, value in (("type", m.marking_type), ("color", m.color)):
                Sdf.AttributeSpec(spec, f"roadtwin:marking:{key}", Sdf.ValueTypeNames.Token,
                                  Sdf.VariabilityVarying, True).default = value
            Sdf.AttributeSpec(spec, "roadtwin:marking:id", Sdf.ValueTypeNames.String,
                              Sdf.VariabilityVarying, True).default = m.id
    _save(layer, geometry)


def _readable_layer(outdir: Path, layer: str, name: str, doc: str) -> Sdf.Layer:
    """``layers/<layer>.usda`` with the stage metadata and an over of the root prim."""
    out = new_layer(outdir / "layers" / f"{layer}.usda", name, doc)
    Sdf.CreatePrimInLayer(out, Sdf.Path(f"/{name}"))
    return out


def _geometry_layer(outdir: Path, layer: str, name: str, doc: str) -> Sdf.Layer:
    """The crate beside ``layers/<layer>.usda`` that holds its meshes' arrays."""
    return new_layer(outdir / "layers" / f"{layer}{GEOMETRY_SUFFIX}", name,
                     f"{doc}: mesh arrays of {layer}.usda (crate, sublayered by it)")


def _no_subdivision(spec: Sdf.PrimSpec) -> None:
    author_uniform(spec, UsdGeom.Tokens.subdivisionScheme, Sdf.ValueTypeNames.Token, UsdGeom.Tokens.none)


def _save(layer: Sdf.Layer, geometry: Sdf.Layer) -> None:
    """Save the crate, then the readable layer sublayering it."""
    geometry.Save()
    layer.subLayerPaths.append(f"./{Path(geometry.realPath).name}")
    layer.Save()


def split_by_owner(m: MergedSegment) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Every owner's :meth:`MergedSegment.part` (same vertices and faces, in the same order), from
    one sort of the segment's (owner, vertex) pairs instead of a mask and a ``np.unique`` per owner."""
    owner = np.asarray(m.face_owner, dtype=np.int64)
    if not len(owner):
        return {}
    faces = np.asarray(m.faces, dtype=np.int64)
    order = np.argsort(owner, kind="stable")
    owners, starts = np.unique(owner[order], return_index=True)
    n = len(m.vertices)
    rank = np.searchsorted(owners, owner[order])
    keys, inverse = np.unique((rank[:, None] * n + faces[order]).ravel(), return_inverse=True)
    key_start = np.searchsorted(keys, np.arange(len(owners)) * n)
    local = inverse.reshape(-1, 3) - key_start[rank][:, None]
    key_end = np.append(key_start[1:], len(keys))
    ends = np.append(starts[1:], len(order))
    return {int(o): (m.vertices[keys[ks:ke] - r * n], local[s:e])
            for r, (o, s, e, ks, ke) in enumerate(zip(owners, starts, ends, key_start, key_end))}


def write_town(outdir: Path, parts: TownParts, on_looks: Callable[[], None] | None = None) -> Path:
    """Every layer but the small root is authored at the Sdf level, each in one change block: no
    stage recomposes while tens of thousands of prims are written. ``on_looks()`` is called once
    ``layers/looks.usda`` is complete (it is written first)."""
    lay = parts.layout
    (outdir / "layers").mkdir(exist_ok=True)
    doc = f"roadtwin town composed from {Path(lay.source).name}"
    split = [split_by_owner(m) for m in parts.merged]
    pieces = _defect_pieces(parts, split)
    marking_names = marking_prim_names(parts.markings)

    # Looks first: ``on_looks`` may hand the town to a preview that reads the materials while the
    # heavy layers are still being written.
    _write_looks_layer(outdir, doc, parts, pieces, marking_names)
    if on_looks is not None:
        on_looks()
    _write_roads(outdir, doc, lay, split)
    _write_defects(outdir, doc, parts, pieces)
    _write_markings(outdir, lay.name, doc, parts.markings, marking_names)
    if parts.props is not None:
        write_props(outdir, lay.name, doc, parts.props)
    _write_physics(outdir, doc, parts, pieces)
    _write_semantics(outdir, doc, parts, marking_names)

    town_path = outdir / "town.usda"
    town = new_layer(town_path, lay.name, doc)  # a layer, not a stage: a stage would compose the whole town here
    layers = [n for n in LAYERS if n != "props" or parts.props is not None]
    town.subLayerPaths = [f"./layers/{n}.usda" for n in layers] + [f"./{parts.layout_file}"]
    top = Sdf.CreatePrimInLayer(town, Sdf.Path(f"/{lay.name}"))
    top.kind = "assembly"
    author_attrs(top, "roadtwin:compose", parts.compose_info)
    town.Save()
    return town_path


_Pieces = dict[int, list[tuple[str, np.ndarray, np.ndarray]]]


def _defect_pieces(parts: TownParts, split: list[dict[int, tuple[np.ndarray, np.ndarray]]]) -> _Pieces:
    """Placement index -> its baked pieces, one per segment it lies on: (segment id, vertices, faces)."""
    pieces: _Pieces = {}
    for seg, parts_of, own in zip(parts.layout.segments, split, parts.owners):
        for local, global_index in enumerate(own):
            if local in parts_of:
                pieces.setdefault(global_index, []).append((seg.id, *parts_of[local]))
    return pieces


def _write_looks_layer(outdir: Path, doc: str, parts: TownParts, pieces: _Pieces, marking_names: list[str]) -> None:
    lay = parts.layout
    root = f"/{lay.name}"
    looks = _readable_layer(outdir, "looks", lay.name, doc + ": materials and their bindings")
    bindings = [(seg.prim_path, kind_material(seg.kind)) for seg in lay.segments if seg.kind not in VARIANT_KINDS]
    for i, p in enumerate(parts.placements):
        material = defect_material_name(p, parts.defect_materials)
        bindings += [(f"{root}/Defects/{p.instance_id}/{seg_id}", material) for seg_id, _, _ in pieces.get(i, [])]
    bindings += [(f"{root}/{MARKING_MESHES}/{name}", marking_material(m.color)) for name, m in zip(marking_names, parts.markings)]
    decals, decal_folders = decal_materials(outdir, parts.placements, parts.library_files)
    write_looks(looks, root, {**parts.materials, **decals}, bindings, road_variants(lay.segments, parts.road_textures),
                parts.road_material, decal_folders)
    looks.Save()


def _write_roads(outdir: Path, doc: str, lay: TownLayout, split: list[dict[int, tuple[np.ndarray, np.ndarray]]]) -> None:
    """The merged road surfaces (owner -1 of each segment), over the layout's segment meshes."""
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    roads = _readable_layer(outdir, "roads", lay.name, doc + ": merged road surfaces")
    geometry = _geometry_layer(outdir, "roads", lay.name, doc)
    with Sdf.ChangeBlock():
        for seg, parts_of in zip(lay.segments, split):
            v, f = parts_of.get(-1, empty)
            author_mesh_geometry(geometry, seg.prim_path, v, f, segment_st(seg, v))
        for seg in lay.segments:
            _no_subdivision(Sdf.CreatePrimInLayer(roads, Sdf.Path(seg.prim_path)))
    _save(roads, geometry)


def _write_defects(outdir: Path, doc: str, parts: TownParts, pieces: _Pieces) -> None:
    """``/<root>/Defects/<instance>``: the placement's attributes and source asset, one mesh per piece."""
    name = parts.layout.name
    root = f"/{name}"
    defects = _readable_layer(outdir, "defects", name, doc + ": defect instances")
    geometry = _geometry_layer(outdir, "defects", name, doc)
    with Sdf.ChangeBlock():
        for i, p in enumerate(parts.placements):
            for seg_id, v, f in pieces.get(i, []):
                author_mesh_geometry(geometry, f"{root}/Defects/{p.instance_id}/{seg_id}", v, f, defect_st(p, v))
        define_prim(defects, f"{root}/Defects", "Xform", "group")
        for i, p in enumerate(parts.placements):
            prim = define_prim(defects, f"{root}/Defects/{p.instance_id}", "Xform", "component")
            attrs = p.attributes()
            author_attrs(prim, "roadtwin:defect", {k: attrs[k] for k in ("type", "depthM", "heightM", "areaM2", "volumeM3")})
            author_attrs(prim, "roadtwin:defect", {"model": attrs["model"], "segments": list(p.segment_ids),
                                                   "poseXYYaw": [p.x, p.y, p.yaw], "scale": list(p.scale)})
            Sdf.AttributeSpec(prim, "roadtwin:source", Sdf.ValueTypeNames.Asset, Sdf.VariabilityVarying, True).default = (
                Sdf.AssetPath("../" + parts.library_files[p.model.name].removeprefix("./")))  # relative to layers/
            for seg_id, _, _ in pieces.get(i, []):
                _no_subdivision(define_prim(defects, f"{root}/Defects/{p.instance_id}/{seg_id}", "Mesh"))
    _save(defects, geometry)


def _write_physics(outdir: Path, doc: str, parts: TownParts, pieces: _Pieces) -> None:
    """Static triangle-mesh collision as overs on the road and defect meshes, and the physics scene."""
    lay = parts.layout
    root = f"/{lay.name}"
    physics = _readable_layer(outdir, "physics", lay.name, doc + ": static road collision")
    colliders = [seg.prim_path for seg in lay.segments]
    colliders += [f"{root}/Defects/{p.instance_id}/{seg_id}" for i, p in enumerate(parts.placements)
                  for seg_id, _, _ in pieces.get(i, [])]
    with Sdf.ChangeBlock():
        scene = define_prim(physics, f"{root}/PhysicsScene", "PhysicsScene")
        Sdf.AttributeSpec(scene, UsdPhysics.Tokens.physicsGravityDirection, Sdf.ValueTypeNames.Vector3f).default = (0.0, 0.0, -1.0)
        Sdf.AttributeSpec(scene, UsdPhysics.Tokens.physicsGravityMagnitude, Sdf.ValueTypeNames.Float).default = 9.81
        for path in colliders:
            author_api_over(physics, path, ["PhysicsCollisionAPI", "PhysicsMeshCollisionAPI"],
                            {"physics:approximation": (Sdf.ValueTypeNames.Token, UsdPhysics.Tokens.none)}, uniform=True)
    physics.Save()


def _write_semantics(outdir: Path, doc: str, parts: TownParts, marking_names: list[str]) -> None:
    lay = parts.layout
    root = f"/{lay.name}"
    sem = _readable_layer(outdir, "semantics", lay.name, doc + ": semantic labels")
    labels = [(seg.prim_path, ["road", seg.kind]) for seg in lay.segments]
    labels += [(f"{root}/Defects/{p.instance_id}", defect_labels(p.model.defect_type, parts.semantic_classes))
               for p in parts.placements]
    labels += [(f"{root}/{MARKING_MESHES}/{name}", ["lane_marking", m.marking_type])
               for name, m in zip(marking_names, parts.markings)]
    with Sdf.ChangeBlock():
        for path, tags in labels:
            author_labels(sem, path, tags)
    sem.Save()
