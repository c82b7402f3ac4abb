"""Town layouts in USD: road segment meshes tagged with ``roadtwin:segment:kind``, composition
rules on the root prim (``roadtwin:rules:*``), optional terrain elevation samples and lane
markings.

Lane markings are ``UsdGeom.BasisCurves`` (linear, one curve each, z = 0 like the planar
segments) under ``/<root>/Markings``, ``widths`` = the paint width and ``purpose = guide``: they
are data that the composer drapes into marking meshes, so renderers (Blender, usdview, Isaac Sim)
must not draw the flat curve itself. Their style is in ``roadtwin:marking:*`` attributes
(``type``/``color`` tokens; ``widthM``, ``dashM``, ``gapM``, ``phaseM``, ``spacingM`` doubles),
the meaning of :class:`~roadtwin_core.model.LaneMarking`.

Map objects (OpenDRIVE objects and signals, :class:`~roadtwin_core.model.MapObject`) are one
``Scope`` ``/<root>/MapObjects`` holding parallel arrays, one row per object (a map's repeated
objects run to thousands: one prim each would be slow to write and read):
``roadtwin:mapObject:`` ``ids``, ``types``, ``subtypes``, ``names``, ``roads`` (string[]), ``kinds``
(token[]: object, signal), ``positions``, ``hpr``, ``sizes`` (double3[]: world x y z; heading pitch
roll in rad; length width height in m, 0 = not given) and ``dynamic`` (bool[]). A layout without
map objects has no such prim.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..errors import RoadtwinError
from ..model import ComposeRules, FixedDefect, LaneMarking, MapObject, RoadSegment, TownLayout
from .checks import FaceBudget, check_points, open_stage
from .stage import _array, new_stage, read_mesh, safe_prim_name, set_kind, write_mesh

SEGMENT_KIND = "roadtwin:segment:kind"
CENTERLINE = "roadtwin:segment:centerline"
TERRAIN = "roadtwin:terrain"
RULES = "roadtwin:rules:"
PLACEMENT = "roadtwin:placement:"
META = "roadtwin:layout:"
MARKING = "roadtwin:marking:"
MAP_OBJECT = "roadtwin:mapObject:"
_MAP_OBJECT_KINDS = ("object", "signal")
_MAP_OBJECT_STRINGS = {"ids": "id", "types": "type", "subtypes": "subtype", "names": "name", "roads": "road"}
_MAP_OBJECT_VECTORS = {"positions": "position", "hpr": "hpr", "sizes": "size"}
_MARKING_NUMBERS = {"widthM": "width_m", "dashM": "dash_m", "gapM": "gap_m", "phaseM": "phase_m",
                    "spacingM": "spacing_m"}
_RULE_ATTRS = {"defectCount": "defect_count", "seed": "seed", "surface": "surface", "merger": "merger",
               "modelsPerType": "models_per_type", "edgeMarginM": "edge_margin_m", "spacingM": "spacing_m",
               "roadEdgeM": "road_edge_m", "wheelPathWeight": "wheel_path_weight", "densityPerKm": "density_per_km",
               "library": "library"}


def open_layout_stage(path: Path) -> Usd.Stage:
    """Open and check a layout: exists, is USD, Z up, meters, has a default prim."""
    stage = open_stage(path, "USD layout file", default_prim=False)
    up = UsdGeom.GetStageUpAxis(stage)
    if up != UsdGeom.Tokens.z:
        raise RoadtwinError(f"{path}: upAxis is {up}; roadtwin layouts must be Z-up (set upAxis = \"Z\")")
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    if not stage.HasAuthoredMetadata("metersPerUnit") or not math.isclose(mpu, 1.0):
        raise RoadtwinError(f"{path}: metersPerUnit is {mpu} (not meters); author metersPerUnit = 1")
    if not stage.GetDefaultPrim():
        raise RoadtwinError(f"{path}: has no defaultPrim")
    return stage


def read_layout(path: str | Path) -> TownLayout:
    path = Path(path)
    stage = open_layout_stage(path)
    root = stage.GetDefaultPrim()
    segments: list[RoadSegment] = []
    fixed: list[FixedDefect] = []
    terrain = None
    markings: list[LaneMarking] = []
    objects: list[MapObject] = []
    budget = FaceBudget(path)
    for prim in Usd.PrimRange(root):
        if prim.HasAttribute(MAP_OBJECT + "positions"):
            objects += _read_map_objects(prim, path)
            continue
        if prim.HasAttribute(MARKING + "type"):
            # Only the curves are layout data; a composed stage's draped marking meshes may carry
            # the same attributes and are not read back as markings.
            if prim.IsA(UsdGeom.BasisCurves):
                markings.append(_read_marking(prim, path))
            continue
        if prim.HasAttribute(PLACEMENT + "type"):
            fixed.append(_read_fixed(prim, path))
            continue
        if prim.HasAttribute(TERRAIN) and prim.IsA(UsdGeom.Points):
            terrain = _array(UsdGeom.Points(prim).GetPointsAttr(), f"{path}: terrain {prim.GetPath()}", np.float64, 3)
            check_points(terrain, f"{path}: terrain {prim.GetPath()}")
            continue
        if not prim.HasAttribute(SEGMENT_KIND):
            continue
        what = f"{path}: segment {prim.GetPath()}"
        if not prim.IsA(UsdGeom.Mesh):
            raise RoadtwinError(f"{what} is a {prim.GetTypeName() or 'typeless prim'}, expected a Mesh "
                                f"(only Mesh prims carry {SEGMENT_KIND})")
        pts, faces = read_mesh(UsdGeom.Mesh(prim), budget=budget)
        if len(pts) < 3 or len(faces) == 0:
            raise RoadtwinError(f"{what} has no triangles")
        if not np.isfinite(pts).all():
            raise RoadtwinError(f"{what} has NaN or inf points")
        center = _array(prim.GetAttribute(CENTERLINE), what, np.float64, 2) if prim.HasAttribute(CENTERLINE) else None
        if center is not None:
            check_points(center, f"{what} {CENTERLINE}")
        attrs = {a.GetName().split(":")[-1]: a.Get() for a in prim.GetAttributes()
                 if a.GetName().startswith("roadtwin:segment:") and a.GetName() not in (SEGMENT_KIND, CENTERLINE)}
        try:
            seg = RoadSegment(prim.GetName(), str(prim.GetAttribute(SEGMENT_KIND).Get()), pts, faces,
                              None if center is None else np.asarray(center, dtype=np.float64), attrs,
                              str(prim.GetPath()))
            seg.polygon()
        except RoadtwinError as exc:
            raise RoadtwinError(f"{what}: {str(exc).split(': ', 1)[-1]}") from None
        segments.append(seg)
    if not segments:
        raise RoadtwinError(f"{path}: no road segments (Mesh prims with {SEGMENT_KIND}) under {root.GetPath()}")
    ids = [s.id for s in segments]
    if len(set(ids)) != len(ids):
        raise RoadtwinError(f"{path}: road segment names must be unique")
    metadata = {a.GetName()[len(META):]: str(a.Get()) for a in root.GetAttributes() if a.GetName().startswith(META)}
    if len({m.id for m in markings}) != len(markings):
        raise RoadtwinError(f"{path}: lane marking names must be unique")
    return TownLayout(root.GetName(), segments, read_rules(root, str(path)), str(path), terrain, fixed, metadata,
                      markings, objects)


def _read_marking(prim: Usd.Prim, path: Path) -> LaneMarking:
    what = f"{path}: lane marking {prim.GetPath()}"
    curves = UsdGeom.BasisCurves(prim)
    pts = _array(curves.GetPointsAttr(), what, np.float64, 3)
    counts = list(_array(curves.GetCurveVertexCountsAttr(), what, np.int64)) or [len(pts)]
    if len(counts) != 1 or counts[0] != len(pts):
        raise RoadtwinError(f"{what}: needs exactly one curve (curveVertexCounts = [{len(pts)}]), got {counts}")
    if not np.isfinite(pts).all():
        raise RoadtwinError(f"{what}: has NaN or inf points")

    def value(key: str, kind: type, default=None):
        attr = prim.GetAttribute(MARKING + key)
        v = attr.Get() if attr and attr.HasAuthoredValue() else None
        if v is None:
            if default is None:
                raise RoadtwinError(f"{what}: needs {MARKING}{key}")
            return default
        number = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
        if kind is float and number:
            return float(v)
        if kind is str and isinstance(v, str):
            return v
        raise RoadtwinError(f"{what}: {MARKING}{key} must be {'a number' if kind is float else 'a token'}, "
                            f"got {v!r}")

    numbers = {field: value(key, float, 0.0 if key != "widthM" else None) for key, field in _MARKING_NUMBERS.items()}
    try:
        return LaneMarking(prim.GetName(), value("type", str), value("color", str, "white"), points=pts[:, :2],
                           **numbers)
    except RoadtwinError as exc:
        raise RoadtwinError(f"{what}: {str(exc).split(': ', 1)[-1]}") from None


def _read_fixed(prim: Usd.Prim, path: Path) -> FixedDefect:
    what = f"{path}: placement {prim.GetPath()}"

    def get(key, default=None):
        attr = prim.GetAttribute(PLACEMENT + key)
        return attr.Get() if attr and attr.HasAuthoredValue() else default

    try:
        params = json.loads(get("params", "{}"))
    except json.JSONDecodeError as exc:
        raise RoadtwinError(f"{what}: params are not valid JSON ({exc.msg})") from None
    pose = get("poseXYYaw")
    if pose is None or len(pose) != 3:
        raise RoadtwinError(f"{what}: needs {PLACEMENT}poseXYYaw = (x, y, yaw)")
    scale = tuple(float(v) for v in get("scale", (1.0, 1.0, 1.0)))
    values = [*map(float, pose), *scale]
    if not all(math.isfinite(v) for v in values) or min(scale) <= 0:
        raise RoadtwinError(f"{what}: pose and scale must be finite and scale positive")
    return FixedDefect(prim.GetName(), str(get("type")), params, float(pose[0]), float(pose[1]), float(pose[2]),
                       scale, int(get("seed", 0)))


def read_rules(root: Usd.Prim, owner: str) -> ComposeRules:
    values = {}
    weights = {}
    for attr in root.GetAttributes():
        name = attr.GetName()
        if not name.startswith(RULES):
            continue
        key = name[len(RULES):]
        value = attr.Get()
        if key.startswith("weight:"):
            weights[key.split(":", 1)[1]] = _rule_value(name, value, float, owner)
        elif key == "kinds":
            if isinstance(value, str) or not hasattr(value, "__iter__"):
                raise RoadtwinError(f"{owner}: rule attribute {name} must be a token[] array, got {value!r}")
            values["kinds"] = tuple(str(v) for v in value)
        elif key in _RULE_ATTRS:
            values[_RULE_ATTRS[key]] = _rule_value(name, value, _RULE_TYPES[key], owner)
        else:
            raise RoadtwinError(f"{owner}: unknown rule attribute {name}")
    rules = ComposeRules(**values)
    if weights:
        rules.type_weights = weights
    return rules.check(owner)


# The Python type each rule attribute must convert to: that of the ComposeRules default.
_RULE_TYPES = {key: type(getattr(ComposeRules(), attr)) for key, attr in _RULE_ATTRS.items()}


def _rule_value(name: str, value, kind: type, owner: str):
    """A rule attribute's value as ``kind``; a wrongly typed attribute is bad input, not a crash."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if kind is str and isinstance(value, str):
        return value
    if kind is float and number:
        return float(value)
    if kind is int and number and float(value).is_integer():
        return int(value)
    want = {str: "a string", float: "a number", int: "an integer"}[kind]
    raise RoadtwinError(f"{owner}: rule attribute {name} must be {want}, got {value!r}")


def write_layout(layout: TownLayout, path: str | Path, doc: str = "") -> Path:
    """Write a layout file (used by the sample-town generator and importers)."""
    path = Path(path)
    stage = new_stage(path, layout.name, doc)
    root = UsdGeom.Xform.Define(stage, f"/{layout.name}").GetPrim()
    set_kind(root, "assembly")
    r = layout.rules
    root.CreateAttribute(RULES + "defectCount", Sdf.ValueTypeNames.Int, custom=True).Set(r.defect_count)
    root.CreateAttribute(RULES + "seed", Sdf.ValueTypeNames.Int, custom=True).Set(r.seed)
    root.CreateAttribute(RULES + "surface", Sdf.ValueTypeNames.String, custom=True).Set(r.surface)
    root.CreateAttribute(RULES + "merger", Sdf.ValueTypeNames.String, custom=True).Set(r.merger)
    root.CreateAttribute(RULES + "kinds", Sdf.ValueTypeNames.TokenArray, custom=True).Set(Vt.TokenArray(list(r.kinds)))
    root.CreateAttribute(RULES + "modelsPerType", Sdf.ValueTypeNames.Int, custom=True).Set(r.models_per_type)
    for key in ("edgeMarginM", "spacingM", "roadEdgeM", "wheelPathWeight", "densityPerKm"):
        root.CreateAttribute(RULES + key, Sdf.ValueTypeNames.Double, custom=True).Set(float(getattr(r, _RULE_ATTRS[key])))
    for t, w in r.type_weights.items():
        root.CreateAttribute(f"{RULES}weight:{t}", Sdf.ValueTypeNames.Double, custom=True).Set(float(w))
    roads = UsdGeom.Xform.Define(stage, f"/{layout.name}/Roads").GetPrim()
    set_kind(roads, "group")
    for seg in layout.segments:
        mesh = UsdGeom.Mesh.Define(stage, f"/{layout.name}/Roads/{safe_prim_name(seg.id)}")
        write_mesh(mesh, seg.vertices, seg.faces)
        prim = mesh.GetPrim()
        set_kind(prim, "component")
        prim.CreateAttribute(SEGMENT_KIND, Sdf.ValueTypeNames.Token, custom=True).Set(seg.kind)
        if seg.centerline is not None:
            prim.CreateAttribute(CENTERLINE, Sdf.ValueTypeNames.Float2Array, custom=True).Set(
                Vt.Vec2fArray.FromNumpy(np.asarray(seg.centerline, dtype=np.float32)))
        for k, v in seg.attributes.items():
            if isinstance(v, str):
                prim.CreateAttribute(f"roadtwin:segment:{k}", Sdf.ValueTypeNames.String, custom=True).Set(v)
            elif isinstance(v, (int, np.integer)):
                prim.CreateAttribute(f"roadtwin:segment:{k}", Sdf.ValueTypeNames.Int, custom=True).Set(int(v))
    for key, value in sorted(layout.metadata.items()):
        root.CreateAttribute(META + key, Sdf.ValueTypeNames.String, custom=True).Set(str(value))
    if layout.fixed:
        set_kind(UsdGeom.Xform.Define(stage, f"/{layout.name}/Placements").GetPrim(), "group")
    for fd in layout.fixed:
        prim = UsdGeom.Xform.Define(stage, f"/{layout.name}/Placements/{safe_prim_name(fd.name)}").GetPrim()
        prim.CreateAttribute(PLACEMENT + "type", Sdf.ValueTypeNames.String, custom=True).Set(fd.defect_type)
        prim.CreateAttribute(PLACEMENT + "params", Sdf.ValueTypeNames.String, custom=True).Set(
            json.dumps(fd.params, sort_keys=True))
        prim.CreateAttribute(PLACEMENT + "poseXYYaw", Sdf.ValueTypeNames.Double3, custom=True).Set((fd.x, fd.y, fd.yaw))
        prim.CreateAttribute(PLACEMENT + "scale", Sdf.ValueTypeNames.Double3, custom=True).Set(tuple(fd.scale))
        prim.CreateAttribute(PLACEMENT + "seed", Sdf.ValueTypeNames.Int, custom=True).Set(int(fd.seed))
    if layout.markings:
        _write_markings(stage, layout)
    if layout.objects:
        _write_map_objects(stage, layout)
    if layout.terrain is not None:
        pts = UsdGeom.Points.Define(stage, f"/{layout.name}/Terrain")
        pts.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(layout.terrain, dtype=np.float32)))
        pts.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
        pts.GetPrim().CreateAttribute(TERRAIN, Sdf.ValueTypeNames.Bool, custom=True).Set(True)
        pts.CreateExtentAttr(UsdGeom.Boundable.ComputeExtentFromPlugins(pts, 0))
    stage.GetRootLayer().Save()
    return path


def _write_markings(stage: Usd.Stage, layout: TownLayout) -> None:
    set_kind(UsdGeom.Xform.Define(stage, f"/{layout.name}/Markings").GetPrim(), "group")
    names: set[str] = set()
    for m in layout.markings:
        name = safe_prim_name(m.id)
        if name in names:
            raise RoadtwinError(f"layout {layout.name}: two lane markings are both named {name!r} in USD")
        names.add(name)
        curves = UsdGeom.BasisCurves.Define(stage, f"/{layout.name}/Markings/{name}")
        pts = np.zeros((len(m.points), 3), dtype=np.float32)
        pts[:, :2] = m.points
        curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
        curves.CreateCurveVertexCountsAttr(Vt.IntArray([len(pts)]))
        curves.CreateTypeAttr(UsdGeom.Tokens.linear)
        curves.CreateWidthsAttr(Vt.FloatArray([m.width_m]))
        curves.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        curves.CreatePurposeAttr(UsdGeom.Tokens.guide)
        curves.CreateExtentAttr(UsdGeom.Boundable.ComputeExtentFromPlugins(curves, Usd.TimeCode.Default()))
        prim = curves.GetPrim()
        prim.CreateAttribute(MARKING + "type", Sdf.ValueTypeNames.Token, custom=True).Set(m.marking_type)
        prim.CreateAttribute(MARKING + "color", Sdf.ValueTypeNames.Token, custom=True).Set(m.color)
        for key, field in _MARKING_NUMBERS.items():
            prim.CreateAttribute(MARKING + key, Sdf.ValueTypeNames.Double, custom=True).Set(float(getattr(m, field)))


def _write_map_objects(stage: Usd.Stage, layout: TownLayout) -> None:
    prim = UsdGeom.Scope.Define(stage, f"/{layout.name}/MapObjects").GetPrim()
    objs = layout.objects
    for key, field in _MAP_OBJECT_STRINGS.items():
        prim.CreateAttribute(MAP_OBJECT + key, Sdf.ValueTypeNames.StringArray, custom=True).Set(
            Vt.StringArray([str(getattr(o, field)) for o in objs]))
    prim.CreateAttribute(MAP_OBJECT + "kinds", Sdf.ValueTypeNames.TokenArray, custom=True).Set(
        Vt.TokenArray([o.kind for o in objs]))
    for key, field in _MAP_OBJECT_VECTORS.items():
        prim.CreateAttribute(MAP_OBJECT + key, Sdf.ValueTypeNames.Double3Array, custom=True).Set(
            Vt.Vec3dArray.FromNumpy(np.array([getattr(o, field) for o in objs], np.float64).reshape(-1, 3)))
    prim.CreateAttribute(MAP_OBJECT + "dynamic", Sdf.ValueTypeNames.BoolArray, custom=True).Set(
        Vt.BoolArray([bool(o.dynamic) for o in objs]))


def _read_map_objects(prim: Usd.Prim, path: Path) -> list[MapObject]:
    what = f"{path}: map objects {prim.GetPath()}"
    cols: dict[str, list] = {}
    for key in (*_MAP_OBJECT_STRINGS, "kinds", *_MAP_OBJECT_VECTORS, "dynamic"):
        attr = prim.GetAttribute(MAP_OBJECT + key)
        value = attr.Get() if attr and attr.HasAuthoredValue() else None
        if value is None:
            raise RoadtwinError(f"{what}: needs {MAP_OBJECT}{key}")
        cols[key] = np.asarray(value, np.float64).reshape(-1, 3) if key in _MAP_OBJECT_VECTORS else list(value)
    n = len(cols["positions"])
    if any(len(v) != n for v in cols.values()):
        raise RoadtwinError(f"{what}: the {MAP_OBJECT}* arrays must all have one row per object ({n})")
    if not all(np.isfinite(cols[k]).all() for k in _MAP_OBJECT_VECTORS) or (cols["sizes"] < 0).any():
        raise RoadtwinError(f"{what}: positions, hpr and sizes must be finite and sizes >= 0")
    bad = sorted(set(cols["kinds"]) - set(_MAP_OBJECT_KINDS))
    if bad:
        raise RoadtwinError(f"{what}: unknown kind {bad[0]!r} (known: {', '.join(_MAP_OBJECT_KINDS)})")
    return [MapObject(cols["ids"][i], str(cols["kinds"][i]), cols["types"][i],
                      tuple(map(float, cols["positions"][i])), tuple(map(float, cols["hpr"][i])),
                      tuple(map(float, cols["sizes"][i])), cols["subtypes"][i], cols["names"][i], cols["roads"][i],
                      bool(cols["dynamic"][i])) for i in range(n)]
