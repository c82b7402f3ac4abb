"""The props layer: ``layers/props.usda`` (+ its crate ``layers/props.geom.usdc``).

Self-contained, so muting it removes the roadside world and nothing else::

    /<root>/Props                          Xform, kind group
        Looks/<material>                   UsdPreviewSurface, constant diffuse / roughness / metallic
        Terrain                            Mesh: the ground under the town (label terrain)
        <Group>                            PointInstancer (Trees, Poles, Wires, Vehicles, Hills ...)
            Prototypes/<prototype>         Xform, LabelsAPI class = [label, prototype]
                <part>                     Mesh bound to its material (trunk, crown ...)

Each prototype's geometry is stored once; instances are rows of the instancer's ``positions``,
``orientations`` (quath), ``scales`` and ``protoIndices``. The heavy arrays (part meshes,
instance arrays, terrain) live in the crate; the ``.usda`` keeps prims, labels, bindings and
``roadtwin:prop:*`` attributes (``rule``: the rule that placed each group, ``place``: how,
``lane`` meaning on a driving lane; ``footprintXY`` on each prototype). Authored at the Sdf level in
one change block; same props, same bytes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

from ..town.prop_shapes import PROP_MATERIALS
from ..town.props import Props
from .stage import GEOMETRY_SUFFIX, author_labels, author_mesh_geometry, author_uniform, define_prim, new_layer

PROPS = "Props"
LAYER = "props"


def _array(spec, name, type_name, value, uniform=False):
    attr = Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying)
    attr.default = value
    return attr


def _flat_normals(spec, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Face-varying normals, one per triangle: the prototypes are faceted low-poly shapes, drawn
    flat by roadtwin's renderer; without normals Blender and Omniverse smooth-shade them (a box
    truck reads as a capsule)."""
    v = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    attr = _array(spec, UsdGeom.Tokens.normals, Sdf.ValueTypeNames.Normal3fArray,
                  Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(np.repeat(n, 3, axis=0), np.float32)))
    attr.SetInfo(UsdGeom.Tokens.interpolation, UsdGeom.Tokens.faceVarying)


def _materials(layer: Sdf.Layer, root: str, names: list[str]) -> None:
    stage = Usd.Stage.Open(layer)
    UsdGeom.Scope.Define(stage, f"{root}/{PROPS}/Looks")
    for name in names:
        rgb, rough, metal = PROP_MATERIALS[name]
        mat = UsdShade.Material.Define(stage, f"{root}/{PROPS}/Looks/{name}")
        surface = UsdShade.Shader.Define(stage, f"{root}/{PROPS}/Looks/{name}/PreviewSurface")
        surface.CreateIdAttr("UsdPreviewSurface")
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(tuple(float(c) for c in rgb))
        surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(rough))
        surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(metal))
        surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
        mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    del stage


def _bind(spec: Sdf.PrimSpec, material: str) -> None:
    ops = spec.GetInfo("apiSchemas")
    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=list(ops.prependedItems) + ["MaterialBindingAPI"]))
    rel = Sdf.RelationshipSpec(spec, UsdShade.Tokens.materialBinding, False)
    rel.targetPathList.explicitItems = [Sdf.Path(material)]


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate (N, K, 3) points by (N, 4) unit quaternions (w, x, y, z)."""
    w, u = q[:, None, :1], q[:, None, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def instancer_extent(group) -> np.ndarray:
    """Bounds of every posed instance (prototype bounding-box corners, scaled, rotated, moved)."""
    boxes = []
    for p in group.prototypes:
        v = np.concatenate([part.vertices for part in p.parts])
        lo, hi = v.min(axis=0), v.max(axis=0)
        boxes.append(np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]))
    corners = np.stack(boxes)[group.proto_indices] * group.scales[:, None, :]
    world = _quat_rotate(group.orientations, corners) + group.positions[:, None, :]
    return np.stack([world.reshape(-1, 3).min(axis=0), world.reshape(-1, 3).max(axis=0)])


def write_props(outdir: Path, root_name: str, doc: str, props: Props) -> Path:
    """Write ``layers/props.usda`` and its crate; returns the ``.usda`` path."""
    root = f"/{root_name}"
    top = f"{root}/{PROPS}"
    path = outdir / "layers" / f"{LAYER}.usda"
    layer = new_layer(path, root_name, doc + ": roadside props (PointInstancers of procedural prototypes)")
    Sdf.CreatePrimInLayer(layer, Sdf.Path(root))
    geometry = new_layer(outdir / "layers" / f"{LAYER}{GEOMETRY_SUFFIX}", root_name,
                         f"{doc}: mesh and instance arrays of {LAYER}.usda (crate, sublayered by it)")
    used = sorted({part.material for g in props.groups for p in g.prototypes for part in p.parts}
                  | ({"ground"} if props.ground is not None else set()))
    define_prim(layer, top, "Xform", "group")
    _materials(layer, root, used)
    with Sdf.ChangeBlock():
        if props.ground is not None:
            v, f = props.ground
            author_mesh_geometry(geometry, f"{top}/Terrain", v, f)
            spec = define_prim(layer, f"{top}/Terrain", "Mesh")
            author_uniform(spec, UsdGeom.Tokens.subdivisionScheme, Sdf.ValueTypeNames.Token, UsdGeom.Tokens.none)
            _bind(spec, f"{top}/Looks/ground")
            author_labels(layer, f"{top}/Terrain", ["terrain", "ground"])
        for g in props.groups:
            ipath = f"{top}/{g.name}"
            inst = define_prim(layer, ipath, "PointInstancer")
            Sdf.AttributeSpec(inst, "roadtwin:prop:rule", Sdf.ValueTypeNames.String, Sdf.VariabilityVarying,
                              True).default = g.rule
            Sdf.AttributeSpec(inst, "roadtwin:prop:place", Sdf.ValueTypeNames.Token, Sdf.VariabilityVarying,
                              True).default = g.place
            protos = []
            define_prim(layer, f"{ipath}/Prototypes", "Scope")
            for p in g.prototypes:
                ppath = f"{ipath}/Prototypes/{p.name}"
                protos.append(Sdf.Path(ppath))
                pspec = define_prim(layer, ppath, "Xform")
                Sdf.AttributeSpec(pspec, "roadtwin:prop:footprintXY", Sdf.ValueTypeNames.DoubleArray,
                                  Sdf.VariabilityVarying, True).default = Vt.DoubleArray(list(p.footprint))
                author_labels(layer, ppath, [p.label, p.name])
                for part in p.parts:
                    mpath = f"{ppath}/{part.name}"
                    author_mesh_geometry(geometry, mpath, part.vertices, part.faces)
                    _flat_normals(Sdf.CreatePrimInLayer(geometry, Sdf.Path(mpath)), part.vertices, part.faces)
                    mspec = define_prim(layer, mpath, "Mesh")
                    author_uniform(mspec, UsdGeom.Tokens.subdivisionScheme, Sdf.ValueTypeNames.Token,
                                   UsdGeom.Tokens.none)
                    _bind(mspec, f"{top}/Looks/{part.material}")
            rel = Sdf.RelationshipSpec(inst, UsdGeom.Tokens.prototypes, False)
            rel.targetPathList.explicitItems = protos
            gspec = Sdf.CreatePrimInLayer(geometry, Sdf.Path(ipath))
            _array(gspec, UsdGeom.Tokens.positions, Sdf.ValueTypeNames.Point3fArray,
                   Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(g.positions, np.float32)))
            _array(gspec, UsdGeom.Tokens.orientations, Sdf.ValueTypeNames.QuathArray,
                   Vt.QuathArray.FromNumpy(np.ascontiguousarray(g.orientations[:, [1, 2, 3, 0]], np.float16)))
            _array(gspec, UsdGeom.Tokens.scales, Sdf.ValueTypeNames.Float3Array,
                   Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(g.scales, np.float32)))
            _array(gspec, UsdGeom.Tokens.protoIndices, Sdf.ValueTypeNames.IntArray,
                   Vt.IntArray.FromNumpy(np.ascontiguousarray(g.proto_indices, np.int32)))
            _array(gspec, UsdGeom.Tokens.extent, Sdf.ValueTypeNames.Float3Array,
                   Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(instancer_extent(g), np.float32)))
    geometry.Save()
    layer.subLayerPaths.append(f"./{LAYER}{GEOMETRY_SUFFIX}")
    layer.Save()
    return path


__all__ = ["LAYER", "PROPS", "instancer_extent", "write_props"]
