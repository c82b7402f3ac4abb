"""A defect type names the material its surface wears (contracts.DefectType ``material``): a
third-party type's instances are bound to the catalog material it names, a type without one
wears the worn asphalt of the road, and a name the catalog does not author is one line at
compose with nothing written. Core's catalog names no type (docs/plugins.md)."""
from __future__ import annotations

import numpy as np
import pytest
import triangle
from pxr import Usd, UsdShade

import roadtwin_cdt
import roadtwin_defects
from roadtwin_core import ComposeRules, FixedDefect, PluginManager, RoadSegment, RoadtwinError, TownLayout, hookimpl
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.usd import write_layout


def _hole(name: str, material: str | None):
    """A pothole generator under another name, wearing ``material`` (None: the attribute left out)."""
    attrs = {"name": name, "description": f"test type {name}"}
    if material is not None:
        attrs["material"] = material
    if material is None:                       # the attribute absent: the contract's default applies
        return type(f"T_{name}", (_NoMaterial,), attrs)()
    return type(f"T_{name}", (roadtwin_defects.Pothole,), attrs)()


class _NoMaterial:
    """The pothole's generator without the pothole's ``material`` (a type that names none)."""
    Params = roadtwin_defects.Pothole.Params
    sample_params = roadtwin_defects.Pothole.sample_params
    generate = roadtwin_defects.Pothole.generate


def _pm(*types) -> PluginManager:
    class Extra:
        @staticmethod
        @hookimpl
        def roadtwin_register_defect_types(register):
            for t in types:
                register(t)

    pm = PluginManager(load_entry_points=False)
    for mod, name in ((roadtwin_cdt, "cdt"), (roadtwin_defects, "defects"), (Extra, "extra")):
        pm.register(mod, name=name)
    return pm


def _layout(tmp_path, fixed):
    verts = np.array([[0.0, -3.5], [30.0, -3.5], [30.0, 3.5], [0.0, 3.5]])
    t = triangle.triangulate({"vertices": verts, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "pqa4")
    road = RoadSegment("r0", "driving", t["vertices"], t["triangles"], np.array([[0.0, 0.0], [30.0, 0.0]]))
    layout = TownLayout("Town", [road], ComposeRules(defect_count=0, seed=1, surface="flat", models_per_type=1,
                                                     type_weights={"pothole": 1.0}))
    layout.fixed = [FixedDefect(f"F{k}", t, {"radius_m": 0.3, "depth_m": 0.05}, x=6.0 + 8 * k, y=0.0, seed=k)
                    for k, t in enumerate(fixed)]
    write_layout(layout, tmp_path / "road.usda")
    return tmp_path / "road.usda"


def _bound(town) -> dict[str, str]:
    stage = Usd.Stage.Open(str(town))
    out = {}
    for prim in stage.GetPrimAtPath("/Town/Defects").GetChildren():
        mat = UsdShade.MaterialBindingAPI(prim.GetChildren()[0]).ComputeBoundMaterial()[0]
        out[prim.GetAttribute("roadtwin:defect:type").Get()] = mat.GetPrim().GetName()
    return out


def test_a_type_wears_the_material_it_names_and_worn_asphalt_by_default(tmp_path):
    pm = _pm(_hole("tarred_hole", "tar"), _hole("plain_hole", None))
    road = _layout(tmp_path, ["tarred_hole", "plain_hole", "pothole"])
    town = compose(road, tmp_path / "town", preview=False, executor="serial", pm=pm).town
    assert _bound(town) == {"tarred_hole": "tar", "plain_hole": "worn", "pothole": "pothole"}
    assert (town.parent / "textures" / "tar_diffuse.png").is_file()


def test_a_material_the_catalog_does_not_author_is_one_line_and_nothing_written(tmp_path):
    pm = _pm(_hole("chrome_hole", "chrome"))
    road = _layout(tmp_path, ["chrome_hole"])
    with pytest.raises(RoadtwinError) as err:
        compose(road, tmp_path / "town", preview=False, executor="serial", pm=pm)
    msg = str(err.value)
    assert "\n" not in msg and "'chrome_hole'" in msg and "'chrome'" in msg
    assert not (tmp_path / "town").exists()
