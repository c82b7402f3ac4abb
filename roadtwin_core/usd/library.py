"""Library assets: an interface file (labels, attributes, extent) that payloads its geometry.

``NAME.usda`` holds what tools query without loading geometry; ``NAME.geom.usda`` holds the
mesh, the boundary loop and the per-vertex pseudo-height flags, so a model round-trips exactly.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

from ..errors import RoadtwinError
from ..looks.catalog import MaterialSpec
from ..model import DefectLook, DefectModel
from .checks import open_stage
from .looks import define_material
from .looks_reader import bound_material
from .stage import _array, apply_labels, new_stage, read_mesh, set_attrs, set_kind, write_mesh

ASSET_SUFFIXES = (".usda", ".usd", ".usdc")   # what an interface file may be
GEOM_SUFFIX = ".geom.usda"                    # its geometry payload, beside it
LOOK_MATERIAL = "Surface"                     # /<asset>/Looks/Surface: a textured asset's own material
LOOK_ROLES = ("diffuse", "roughness", "normal")
ST_AFFINE_TOLERANCE = 1e-4                    # st must be affine in local XY to be a decal (st units)
DEPTH_SCALE_PARAM = "depth_scale"             # params entry of a model whose depth is not in measured metres


def is_asset_file(path: Path) -> bool:
    """Whether ``path`` may be a library asset's interface file: a visible USD file (not a
    temporary of an atomic write) that is not a geometry payload. The one rule ``library list``,
    ``library add`` and ``compose --library`` share."""
    return (path.suffix in ASSET_SUFFIXES and not path.name.endswith(GEOM_SUFFIX)
            and not path.name.startswith("."))


def library_asset_files(folder: Path) -> list[Path]:
    """The interface files of a library folder, sorted (geometry payloads excluded)."""
    return [p for p in sorted(folder.iterdir()) if p.is_file() and is_asset_file(p)]


DEFECT_CLASS = "road_defect"


def defect_labels(defect_type: str, semantic_classes: dict[str, str] | None = None) -> list[str]:
    """UsdSemantics "class" labels of a defect instance or asset: ``["road_defect", <type>]``;
    a type whose class is another (a look-alike: ``road_lookalike``) is road first:
    ``["road", <class>, <type>]``, so a consumer that reads the first label counts it as road."""
    cls = (semantic_classes or {}).get(defect_type, DEFECT_CLASS)
    return [DEFECT_CLASS, defect_type] if cls == DEFECT_CLASS else ["road", cls, defect_type]


def write_defect_asset(model: DefectModel, path: str | Path, semantic_class: str = DEFECT_CLASS) -> Path:
    path = Path(path)
    name = model.name
    depth_scale = _depth_scale(model)          # checked before anything is written
    geom_path = path.with_name(f"{path.stem}{GEOM_SUFFIX}")
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
    if model.look is not None:
        st = UsdGeom.PrimvarsAPI(prim).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(model.look.st(model.vertices), dtype=np.float32)))
    gstage.GetRootLayer().Save()

    stage = new_stage(path, name, f"roadtwin defect asset: {name}")
    asset = UsdGeom.Xform.Define(stage, f"/{name}")
    p = asset.GetPrim()
    set_kind(p, "component")
    apply_labels(p, defect_labels(model.defect_type, {model.defect_type: semantic_class}))
    set_attrs(p, "roadtwin:defect", {k: v for k, v in model.attributes().items() if k != "source"})
    set_attrs(p, "roadtwin", {"source": model.source, "params": json.dumps(model.params, sort_keys=True)})
    if depth_scale is not None:
        _write_depth_scale(p, depth_scale)
    lo, hi = model.vertices.min(axis=0), model.vertices.max(axis=0)
    UsdGeom.ModelAPI(p).SetExtentsHint(Vt.Vec3fArray([tuple(lo.tolist()), tuple(hi.tolist())]))
    p.GetPayloads().AddPayload(f"./{geom_path.name}")
    if model.look is not None:
        _write_look(stage, p, model, path.parent)
    stage.GetRootLayer().Save()
    del root
    return path


def _depth_scale(model: DefectModel) -> dict | None:
    """``model.params["depth_scale"]``: how the model's depth was scaled when not measured metres
    (``{"kind": "nominal", <the numbers used>}``); None when it does not say."""
    mark = model.params.get(DEPTH_SCALE_PARAM)
    if mark is not None and (not isinstance(mark, dict) or not isinstance(mark.get("kind"), str) or not mark["kind"]):
        raise RoadtwinError(f"defect model {model.name!r}: params[{DEPTH_SCALE_PARAM!r}] must be a dict with a "
                            f"string 'kind', got {mark!r}")
    return mark


def _write_depth_scale(prim: Usd.Prim, mark: dict) -> None:
    """``roadtwin:depthScale`` = the mark's kind, its customData the numbers the scale came from,
    so a tool sees it without parsing params; kept in params too, it survives a read and
    re-write (a town's library/)."""
    attr = prim.CreateAttribute("roadtwin:depthScale", Sdf.ValueTypeNames.String, custom=True)
    attr.Set(mark["kind"])
    basis = {k: v for k, v in sorted(mark.items()) if k != "kind" and isinstance(v, (str, int, float))}
    if basis:
        attr.SetCustomData(basis)


def look_texture_files(model: DefectModel) -> dict[str, str]:
    """Role -> file name under ``textures/`` beside the asset, where :func:`write_defect_asset`
    copies a textured model's look (a composed town's decal materials point at these copies)."""
    return {role: f"{model.name}_{role}{Path(src).suffix}" for role in LOOK_ROLES
            if (src := model.look.textures.get(role))}


def _write_look(stage: Usd.Stage, prim: Usd.Prim, model: DefectModel, folder: Path) -> None:
    """The asset's own texture: files copied to ``textures/<name>_<role>.png`` beside the asset and
    a ``UsdPreviewSurface`` (looks layer network, clamped, opacity from alpha) bound to it."""
    files = look_texture_files(model)
    (folder / "textures").mkdir(exist_ok=True)
    for role, name in files.items():
        src, dst = model.look.textures[role], folder / "textures" / name
        if not dst.exists() or not dst.samefile(src):
            shutil.copyfile(src, dst)
    if "diffuse" not in files:
        raise RoadtwinError(f"defect model {model.name!r}: its look has no diffuse texture")
    spec = MaterialSpec(LOOK_MATERIAL, files["diffuse"], files.get("roughness"), normal=files.get("normal"),
                        wrap="clamp", opacity_from_alpha=True,
                        doc=f"the defect's own texture (source: {model.source}); alpha fades into the road")
    UsdGeom.Scope.Define(stage, f"{prim.GetPath()}/Looks")
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(define_material(stage, str(prim.GetPath()), spec, "./textures"))


def read_look(mesh_prim: Usd.Prim, points: np.ndarray) -> DefectLook | None:
    """A textured asset's look: the bound material's texture files and its st as an affine map
    of local XY (None when there is no textured material roadtwin reads, or st is not affine:
    not a decal; the asset then wears its type's material like a parametric one)."""
    try:
        material = bound_material(mesh_prim, {})      # a binding on the root prim is inherited
    except RoadtwinError:
        return None
    pv = UsdGeom.PrimvarsAPI(mesh_prim).GetPrimvar(material.st_name if material else "st")
    if material is None or material.diffuse_texture is None or not material.diffuse_texture.path or not pv:
        return None
    st = pv.ComputeFlattened() if pv.GetInterpolation() in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) else None
    if st is None or len(st) != len(points):
        return None
    textures = {role: t.path for role, t in (("diffuse", material.diffuse_texture),
                                             ("roughness", material.roughness_texture),
                                             ("normal", material.normal_texture)) if t is not None and t.path}
    return DefectLook.fit(textures, points, st, ST_AFFINE_TOLERANCE)


def read_defect_asset(path: str | Path) -> DefectModel:
    """A library asset back as a DefectModel; anything missing or malformed is one RoadtwinError
    naming the file (and prim), since library folders hold files from other tools too."""
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such defect asset")
    stage = open_stage(path, "defect asset")
    root = stage.GetDefaultPrim()
    type_attr = root.GetAttribute("roadtwin:defect:type")
    defect_type = type_attr.Get() if type_attr else None
    if not isinstance(defect_type, str) or not defect_type:
        raise RoadtwinError(f"{path}: not a defect asset (needs a string roadtwin:defect:type on {root.GetPath()})")
    mesh_prim = next((p for p in Usd.PrimRange(root) if p.IsA(UsdGeom.Mesh)), None)
    if mesh_prim is None:
        raise RoadtwinError(f"{path}: defect asset has no Mesh prim under {root.GetPath()} (payload missing?)")
    where = f"{path}: mesh {mesh_prim.GetPath()}"
    pts, faces = read_mesh(UsdGeom.Mesh(mesh_prim), world=False)
    if len(faces) == 0:
        raise RoadtwinError(f"{where} has no triangles")
    area = 0.5 * np.linalg.norm(np.cross(pts[faces[:, 1]] - pts[faces[:, 0]], pts[faces[:, 2]] - pts[faces[:, 0]]), axis=1)
    if not area.sum() > 0:
        raise RoadtwinError(f"{where}: every triangle has zero area")
    loop_attr = mesh_prim.GetAttribute("roadtwin:defect:boundaryLoop")
    loop = _array(loop_attr, where, np.int64) if loop_attr else np.zeros(0, dtype=np.int64)
    if len(loop) < 3 or loop.min() < 0 or loop.max() >= len(pts):
        raise RoadtwinError(f"{where}: roadtwin:defect:boundaryLoop needs at least 3 indices of its {len(pts)} points")
    flags = UsdGeom.PrimvarsAPI(mesh_prim).GetPrimvar("roadtwin:pseudoHeight").Get()
    if flags is not None:
        flags = _array(UsdGeom.PrimvarsAPI(mesh_prim).GetPrimvar("roadtwin:pseudoHeight").GetAttr(), where, bool)
        if len(flags) != len(pts):
            raise RoadtwinError(f"{where}: primvars:roadtwin:pseudoHeight has {len(flags)} values for {len(pts)} points")
    raw = root.GetAttribute("roadtwin:params").Get() if root.HasAttribute("roadtwin:params") else "{}"
    try:
        params = json.loads(raw)
        if not isinstance(params, dict):
            raise ValueError
    except (TypeError, ValueError):
        raise RoadtwinError(f"{path}: roadtwin:params on {root.GetPath()} is not a JSON object") from None
    source = root.GetAttribute("roadtwin:source").Get() if root.HasAttribute("roadtwin:source") else None
    try:
        return DefectModel(root.GetName(), defect_type, pts, faces, loop, flags, str(source or path.name), params,
                           read_look(mesh_prim, pts))
    except RoadtwinError as exc:
        raise RoadtwinError(f"{path}: {str(exc).split(': ', 1)[-1]}") from None
