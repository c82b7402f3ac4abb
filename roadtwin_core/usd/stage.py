"""Small helpers every layer writer uses: metadata, kinds, labels, typed custom attributes,
texture coordinates (the st convention of :mod:`roadtwin_core.looks`) and safe prim names; and
the mesh reader every reader uses, checked on the way in by :mod:`.checks` (which imports
nothing of this module: the dependency goes one way)."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Kind, Sdf, Usd, UsdGeom, UsdPhysics, UsdSemantics, Vt

from ..errors import RoadtwinError
from ..looks.catalog import ST_TILE_M
from .checks import FaceBudget, check_points

LABEL_TAXONOMY = "class"
GEOMETRY_SUFFIX = ".geom.usdc"  # layers/<name>.usda sublayers layers/<name>.geom.usdc (its mesh arrays, crate)


def new_stage(path: Path, default_prim: str, doc: str = "") -> Usd.Stage:
    """A new layer with Z up, meters, kilograms and a defaultPrim (which callers then define/over)."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    stage.GetRootLayer().defaultPrim = default_prim
    if doc:
        stage.GetRootLayer().documentation = doc
    return stage


def new_layer(path: Path, default_prim: str, doc: str = "") -> Sdf.Layer:
    """:func:`new_stage`'s metadata on a bare ``Sdf.Layer`` (crate when the suffix is ``.usdc``):
    geometry is authored at the Sdf level, with no stage recomposing after every edit."""
    layer = Sdf.Layer.CreateNew(str(path))
    info = layer.pseudoRoot
    info.SetInfo("upAxis", UsdGeom.Tokens.z)
    info.SetInfo("metersPerUnit", 1.0)
    info.SetInfo("kilogramsPerUnit", 1.0)
    layer.defaultPrim = default_prim
    if doc:
        layer.documentation = doc
    return layer


def _array_attr(spec: Sdf.PrimSpec, name: str, type_name, value) -> Sdf.AttributeSpec:
    attr = Sdf.AttributeSpec(spec, name, type_name)
    attr.default = value
    return attr


def author_mesh_geometry(layer: Sdf.Layer, path: str, vertices: np.ndarray, faces: np.ndarray,
                         st: np.ndarray | None = None) -> None:
    """Over ``path`` in ``layer`` with a triangle mesh's heavy arrays (points, face counts and
    indices, extent, vertex ``primvars:st``), each array handed over from numpy in one call.

    Only the arrays: the prim's type, kind and small attributes live in the readable layer that
    sublayers this one, so each array is authored exactly once. Call inside ``Sdf.ChangeBlock``."""
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(path))
    pts = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    tris = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    _array_attr(spec, UsdGeom.Tokens.points, Sdf.ValueTypeNames.Point3fArray, Vt.Vec3fArray.FromNumpy(pts))
    _array_attr(spec, UsdGeom.Tokens.faceVertexCounts, Sdf.ValueTypeNames.IntArray,
                Vt.IntArray.FromNumpy(np.full(len(tris), 3, dtype=np.int32)))
    _array_attr(spec, UsdGeom.Tokens.faceVertexIndices, Sdf.ValueTypeNames.IntArray, Vt.IntArray.FromNumpy(tris.ravel()))
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(3, np.float32),) * 2
    _array_attr(spec, UsdGeom.Tokens.extent, Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray.FromNumpy(np.stack([lo, hi])))
    if st is not None:
        attr = _array_attr(spec, "primvars:st", Sdf.ValueTypeNames.TexCoord2fArray,
                           Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(st, dtype=np.float32).reshape(-1, 2)))
        attr.SetInfo(UsdGeom.Tokens.interpolation, UsdGeom.Tokens.vertex)


def author_api_over(layer: Sdf.Layer, path: str, schemas: list[str], attrs: dict[str, tuple[Any, Any]],
                    uniform: bool = False) -> None:
    """Over ``path`` in ``layer`` applying API ``schemas`` (prepended, as ``Apply`` does) with
    ``attrs`` (name -> (value type, value)): what ``XxxAPI.Apply(prim)`` + ``CreateXxxAttr`` write,
    at the Sdf level, so thousands of overs need no stage to recompose. Call inside ``Sdf.ChangeBlock``."""
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(path))
    ops = spec.GetInfo("apiSchemas")
    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=list(ops.prependedItems) + list(schemas)))
    for name, (type_name, value) in attrs.items():
        attr = Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying)
        attr.default = value


def author_labels(layer: Sdf.Layer, path: str, labels: list[str], taxonomy: str = LABEL_TAXONOMY) -> None:
    """:func:`apply_labels` at the Sdf level (same specs; see :func:`author_api_over`)."""
    author_api_over(layer, path, [f"SemanticsLabelsAPI:{taxonomy}"],
                    {f"semantics:labels:{taxonomy}": (Sdf.ValueTypeNames.TokenArray, Vt.TokenArray(labels))})


def set_kind(prim: Usd.Prim, kind: str) -> None:
    Usd.ModelAPI(prim).SetKind({"assembly": Kind.Tokens.assembly, "group": Kind.Tokens.group,
                               "component": Kind.Tokens.component}[kind])


def apply_labels(prim: Usd.Prim, labels: list[str], taxonomy: str = LABEL_TAXONOMY) -> None:
    """UsdSemantics.LabelsAPI (Isaac Sim 5+ / Replicator read this); inherited by descendants."""
    api = UsdSemantics.LabelsAPI.Apply(prim, taxonomy)
    api.CreateLabelsAttr().Set(Vt.TokenArray(labels))


_TYPES = {bool: Sdf.ValueTypeNames.Bool, int: Sdf.ValueTypeNames.Int, float: Sdf.ValueTypeNames.Double,
          str: Sdf.ValueTypeNames.String}


def _typed(value: Any) -> tuple[Any, Any]:
    """(value type, value) of a custom attribute: string lists -> string[], other lists -> double[]."""
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        return Sdf.ValueTypeNames.StringArray, Vt.StringArray(list(value))
    if isinstance(value, (list, tuple, np.ndarray)):
        return Sdf.ValueTypeNames.DoubleArray, Vt.DoubleArray(np.asarray(value, dtype=np.float64).ravel().tolist())
    if isinstance(value, (np.floating, np.integer)):
        return _TYPES[float if isinstance(value, np.floating) else int], value.item()
    return _TYPES[type(value)], value


def set_attrs(prim: Usd.Prim, namespace: str, values: dict[str, Any]) -> None:
    """Custom attributes ``namespace:key`` with units in the key (``depthM``); lists become arrays."""
    for key, value in values.items():
        type_name, typed = _typed(value)
        prim.CreateAttribute(f"{namespace}:{key}", type_name, custom=True).Set(typed)


def author_attrs(spec: Sdf.PrimSpec, namespace: str, values: dict[str, Any]) -> None:
    """:func:`set_attrs` at the Sdf level (same specs), for writers that author thousands of prims."""
    for key, value in values.items():
        type_name, typed = _typed(value)
        Sdf.AttributeSpec(spec, f"{namespace}:{key}", type_name, Sdf.VariabilityVarying, True).default = typed


def define_prim(layer: Sdf.Layer, path: str, type_name: str = "", kind: str | None = None) -> Sdf.PrimSpec:
    """What ``Stage.DefinePrim`` (or ``UsdGeom.Xxx.Define``) + :func:`set_kind` write into a
    layer of its own, at the Sdf level: a ``def`` spec, and ancestors that are only overs become
    typeless ``def`` s. Thousands of prims need no stage to recompose. Call inside ``Sdf.ChangeBlock``."""
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(path))
    parent = spec
    while parent and parent.path != Sdf.Path.absoluteRootPath and parent.specifier != Sdf.SpecifierDef:
        parent.specifier = Sdf.SpecifierDef
        parent = parent.nameParent
    if type_name:
        spec.typeName = type_name
    if kind:
        spec.kind = kind
    return spec


def author_uniform(spec: Sdf.PrimSpec, name: str, type_name, value) -> Sdf.AttributeSpec:
    """A schema (non-custom) uniform attribute, e.g. ``subdivisionScheme``."""
    attr = Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityUniform)
    attr.default = value
    return attr


def write_mesh(mesh: UsdGeom.Mesh, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Triangle mesh, polygonal (no subdivision), with extent."""
    pts = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(vertices, dtype=np.float32))
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces, dtype=np.int32).ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lo, hi = pts_bounds(vertices)
    mesh.CreateExtentAttr(Vt.Vec3fArray([lo, hi]))


def pts_bounds(vertices: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    v = np.asarray(vertices, dtype=np.float32)
    return tuple(v.min(axis=0).tolist()), tuple(v.max(axis=0).tolist())


def read_mesh(mesh: UsdGeom.Mesh, world: bool = True, budget=None) -> tuple[np.ndarray, np.ndarray]:
    """Points (world space unless told) and triangulated faces (fan split of polygons).

    Checked on the way in (one RoadtwinError naming file and prim): topology, finite points
    near the origin, and the triangle budget (``budget``: a :class:`.checks.FaceBudget` shared by
    every mesh of a file; without one only the per-mesh limit applies)."""
    where = _mesh_where(mesh)
    pts = _array(mesh.GetPointsAttr(), where, np.float64, 3)
    counts = _array(mesh.GetFaceVertexCountsAttr(), where, np.int64)
    idx = _array(mesh.GetFaceVertexIndicesAttr(), where, np.int64)
    _check_topology(mesh, len(pts), counts, idx)
    (budget or FaceBudget(where)).take(int((counts - 2).sum()) if len(counts) else 0, where)
    check_points(pts, where)
    if world and len(pts):
        m = np.asarray(mesh.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64)
        if not np.isfinite(m).all():
            raise RoadtwinError(f"{where}: its transform has NaN or infinite entries")
        pts = pts @ m[:3, :3] + m[3, :3]
        check_points(pts, f"{where} (world space)")
    _face, corners = fan_corners(counts)
    return pts, idx[corners].reshape(-1, 3)


def check_stage_meshes(stage: Usd.Stage, path: str | Path) -> int:
    """Every Mesh of a stage (instance proxies included) reads cleanly: topology, finite points
    near the origin, triangle budget. Returns the number of meshes. Exporters and validators
    then never meet geometry that would crash them with an error naming no file."""
    budget = FaceBudget(path)
    n = 0
    for prim in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdGeom.Mesh):
            read_mesh(UsdGeom.Mesh(prim), budget=budget)
            n += 1
    return n


def fan_corners(counts) -> tuple[np.ndarray, np.ndarray]:
    """The fan split of USD polygons every reader shares: for each triangle, its polygon (T,) and
    its three face-vertex positions (T, 3) into ``faceVertexIndices`` (face f with c corners
    starting at s gives (s, s+k, s+k+1), k = 1..c-2; faces under 3 corners give none)."""
    counts = np.asarray(counts, dtype=np.int64)
    n_tri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), n_tri)
    first = np.repeat(np.cumsum(counts) - counts, n_tri)
    k = np.arange(len(face)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    return face, np.stack([first, first + k, first + k + 1], axis=1).reshape(-1, 3)


def _mesh_where(mesh: UsdGeom.Mesh) -> str:
    layer = mesh.GetPrim().GetStage().GetRootLayer()
    return f"{layer.realPath or layer.identifier}: mesh {mesh.GetPath()}"


def _array(attr, where: str, dtype, width: int = 0) -> np.ndarray:
    """An attribute's array value as numpy; a wrongly typed value (a string where points belong)
    is bad input named by attribute, not a ValueError from numpy."""
    value = attr.Get() if attr else None
    if value is None:
        return np.zeros((0, width) if width else 0, dtype=dtype)
    try:
        arr = np.asarray(value, dtype=dtype)
        if width:
            if arr.ndim != 2 or arr.shape[1] != width:
                raise ValueError
        elif arr.ndim != 1:
            raise ValueError
    except (TypeError, ValueError):
        raise RoadtwinError(f"{where}: {attr.GetName()} is not an array of "
                            f"{f'{width}-vectors' if width else 'integers'} ({attr.GetTypeName()})") from None
    return arr


def safe_prim_name(name: str, empty: str = "_", lead: str = "_") -> str:
    """A valid USD prim name from any id or file stem (``road1_lane-1.0`` -> ``road1_lane_1_0``):
    every character but ASCII letters, digits and ``_`` becomes ``_``; an empty result becomes
    ``empty``; ``lead`` goes before a leading digit (``lead=""`` for a piece of a longer name)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not name:
        return empty
    return f"{lead}{name}" if name[0].isdigit() else name


def planar_st(vertices: np.ndarray) -> np.ndarray:
    """World-planar texture coordinates: one st unit per ``ST_TILE_M`` metres of x and y."""
    return np.asarray(vertices, dtype=np.float64)[:, :2] / ST_TILE_M


def lane_st(vertices: np.ndarray, centerline: np.ndarray) -> np.ndarray:
    """Lane-aligned texture coordinates: u = arc length along the centreline / ``ST_TILE_M``,
    v = 0.5 + signed lateral offset (left of travel positive) / ``ST_TILE_M``.

    Each point takes its nearest centreline piece; beyond the ends the first and last pieces are
    extended, so u keeps growing linearly (negative before the start)."""
    xy = np.asarray(vertices, dtype=np.float64)[:, :2]
    c = np.asarray(centerline, dtype=np.float64).reshape(-1, 2)
    d = np.diff(c, axis=0)
    length = np.linalg.norm(d, axis=1)
    keep = length > 1e-9
    if not keep.any():
        return planar_st(vertices)
    a, d, length = c[:-1][keep], d[keep], length[keep]
    station = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    # x and y apart as (P,S) planes: a (P,S,2) array summed over its last axis costs several times more
    rx, ry = xy[:, 0, None] - a[None, :, 0], xy[:, 1, None] - a[None, :, 1]
    t = (rx * d[None, :, 0] + ry * d[None, :, 1]) / length[None] ** 2
    lo = np.zeros(len(a)); lo[0] = -np.inf
    hi = np.ones(len(a)); hi[-1] = np.inf
    t = np.clip(t, lo[None], hi[None])
    ex, ey = rx - t * d[None, :, 0], ry - t * d[None, :, 1]
    k = (ex * ex + ey * ey).argmin(axis=1)
    rows = np.arange(len(xy))
    s = station[k] + t[rows, k] * length[k]
    lateral = (d[k, 0] * ry[rows, k] - d[k, 1] * rx[rows, k]) / length[k]
    return np.column_stack([s / ST_TILE_M, 0.5 + lateral / ST_TILE_M])


def _check_topology(mesh: UsdGeom.Mesh, n_points: int, counts: np.ndarray, idx: np.ndarray) -> None:
    """Malformed geometry is bad input, named by file and prim, not an IndexError later."""
    prim = mesh.GetPrim()
    where = f"{prim.GetStage().GetRootLayer().realPath or prim.GetStage().GetRootLayer().identifier}: mesh {prim.GetPath()}"
    if len(counts) and counts.min() < 3:
        raise RoadtwinError(f"{where}: faceVertexCounts has a face with {int(counts.min())} vertices (need >= 3)")
    if int(counts.sum()) != len(idx):
        raise RoadtwinError(f"{where}: faceVertexCounts add up to {int(counts.sum())} but faceVertexIndices "
                            f"has {len(idx)} entries")
    if len(idx) and (idx.min() < 0 or idx.max() >= n_points):
        bad = int(idx.max()) if idx.max() >= n_points else int(idx.min())
        raise RoadtwinError(f"{where}: faceVertexIndices refers to point {bad}, but there are {n_points} points")
