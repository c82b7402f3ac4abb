"""Library assets: an interface file (labels, attributes, extent) that payloads its geometry.

``NAME.usda`` holds what tools query without loading geometry; ``NAME.geom.usda`` holds the
mesh, the boundary loop and the per-vertex pseudo-height flags, so a model round-trips exactly.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..errors import RoadtwinError
from ..model import DefectModel
from .stage import apply_labels, new_stage, read_mesh, set_attrs, set_kind, write_mesh


def write_defect_asset(model: DefectModel, path: str | Path) -> Path:
    path = Path(path)
    name = model.name
    geom_path = path.with_name(f"{path.stem}.geom.usda")
    gstage = new_stage(geom_path, name, f"roadtwin defect geometry: {name}")
    root = UsdGeom.Xform.Define(gstage, f"/{name}")
    mesh = UsdGeom.Mesh.Define(gstage, f"/{name}/mesh")
    write_mesh(mesh, model.vertices, model.faces)
    prim = mesh.GetPrim()
    prim.CreateAttribute("roadtwin:defect:boundaryLoop", Sdf.ValueTypeNames.IntArray, custom=True).Set(
        Vt.IntArray.FromNumpy(model.boundary.astype(np.int32)))
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("roadtwin:pseudoHeight", Sdf.ValueTypeNames.BoolArray,
                                                 UsdGeom.Tokens.vertex)
    pv.Set(Vt.BoolArray([bool(b) for b in model.pseudo_height]))
    gstage.GetRootLayer().Save()

    stage = new_stage(path, name, f"roadtwin defect asset: {name}")
    asset = UsdGeom.Xform.Define(stage, f"/{name}")
    p = asset.GetPrim()
    set_kind(p, "component")
    apply_labels(p, ["road_defect", model.defect_type])
    set_attrs(p, "roadtwin:defect", {k: v for k, v in model.attributes().items() if k != "source"})
    set_attrs(p, "roadtwin", {"source": model.source, "params": json.dumps(model.params, sort_keys=True)})
    lo, hi = model.vertices.min(axis=0), model.vertices.max(axis=0)
    UsdGeom.ModelAPI(p).SetExtentsHint(Vt.Vec3fArray([tuple(lo.tolist()), tuple(hi.tolist())]))
    p.GetPayloads().AddPayload(f"./{geom_path.name}")
    stage.GetRootLayer().Save()
    del root
    return path


def read_defect_asset(path: str | Path) -> DefectModel:
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such defect asset")
    stage = Usd.Stage.Open(str(path))
    root = stage.GetDefaultPrim()
    if not root:
        raise RoadtwinError(f"{path}: defect asset has no defaultPrim")
    mesh_prim = next((p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Mesh)), None)
    if mesh_prim is None:
        raise RoadtwinError(f"{path}: defect asset has no mesh (payload missing?)")
    pts, faces = read_mesh(UsdGeom.Mesh(mesh_prim), world=False)
    loop = np.asarray(mesh_prim.GetAttribute("roadtwin:defect:boundaryLoop").Get(), dtype=np.int64)
    flags = UsdGeom.PrimvarsAPI(mesh_prim).GetPrimvar("roadtwin:pseudoHeight").Get()
    params = root.GetAttribute("roadtwin:params").Get() if root.HasAttribute("roadtwin:params") else "{}"
    return DefectModel(root.GetName(), str(root.GetAttribute("roadtwin:defect:type").Get()), pts, faces, loop,
                       None if flags is None else np.asarray(flags, dtype=bool),
                       str(root.GetAttribute("roadtwin:source").Get() or path.name), json.loads(params))
