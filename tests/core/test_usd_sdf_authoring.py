"""The town writer authors its layers at the Sdf level (no stage recomposing per prim); each
helper must write exactly what the Usd API it replaces writes, and the per-owner split must give
exactly :meth:`MergedSegment.part`."""
import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from roadtwin_core.model import MergedSegment
from roadtwin_core.usd.looks import _bind
from roadtwin_core.usd.stage import author_attrs, author_uniform, define_prim, set_attrs, set_kind
from roadtwin_core.usd.town import split_by_owner

VALUES = {"type": "pothole", "depthM": 0.05, "count": 3, "flag": True, "segments": ["a", "b"],
          "poseXYYaw": [1.0, 2.0, 0.5], "npf": np.float32(0.25), "npi": np.int64(7)}


def _usd_reference() -> str:
    stage = Usd.Stage.CreateInMemory()
    stage.OverridePrim("/Town")
    set_kind(UsdGeom.Xform.Define(stage, "/Town/Defects").GetPrim(), "group")
    prim = UsdGeom.Xform.Define(stage, "/Town/Defects/D0").GetPrim()
    set_kind(prim, "component")
    set_attrs(prim, "roadtwin:defect", VALUES)
    UsdGeom.Mesh.Define(stage, "/Town/Defects/D0/seg").CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mat = UsdShade.Material.Define(stage, "/Town/Looks/pothole")
    UsdShade.MaterialBindingAPI.Apply(stage.OverridePrim("/Town/Roads/r0")).Bind(mat)
    return stage.GetRootLayer().ExportToString()


def _sdf_version() -> str:
    layer = Sdf.Layer.CreateAnonymous(".usda")
    with Sdf.ChangeBlock():
        Sdf.CreatePrimInLayer(layer, Sdf.Path("/Town"))
        define_prim(layer, "/Town/Defects", "Xform", "group")
        author_attrs(define_prim(layer, "/Town/Defects/D0", "Xform", "component"), "roadtwin:defect", VALUES)
        author_uniform(define_prim(layer, "/Town/Defects/D0/seg", "Mesh"), "subdivisionScheme",
                       Sdf.ValueTypeNames.Token, "none")
        define_prim(layer, "/Town/Looks/pothole", "Material")
        _bind(layer, "/Town", [("/Town/Roads/r0", "pothole")], {"pothole"})
    return layer.ExportToString()


def test_sdf_helpers_write_what_the_usd_api_writes():
    assert _sdf_version() == _usd_reference()


def test_split_by_owner_equals_part_per_owner():
    rng = np.random.default_rng(3)
    verts = rng.random((40, 3))
    faces = rng.integers(0, 40, (60, 3))
    owner = rng.integers(-1, 4, 60)
    owner[owner == 2] = -1  # an owner with no faces is absent
    m = MergedSegment("s", verts, faces, owner)
    split = split_by_owner(m)
    assert sorted(split) == sorted(set(owner.tolist()))
    for o, (v, f) in split.items():
        ref_v, ref_f = m.part(o)
        np.testing.assert_array_equal(v, ref_v)
        np.testing.assert_array_equal(f, ref_f)
