"""Props in the ray-cast renderer (roadtwin_warp_render, CPU): a utility pole's shadow lands on
the road where the sun direction says, and the pole is drawn and labelled.

Through the real path: the props layer written to disk, read back by ``load_town`` (its
PointInstancer expanded), turned into the render mesh. Closed form: a point at height h casts
its shadow h / tan(elevation) away from its foot, opposite the sun's azimuth.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf

from roadtwin_core.render import Camera, Intrinsics, RenderParams, build_render_mesh, look_from
from roadtwin_core.town.prop_shapes import make_prototype
from roadtwin_core.town.props import PropGroup, Props
from roadtwin_core.usd.props import write_props
from roadtwin_core.usd.stage import author_mesh_geometry, define_prim, new_layer
from roadtwin_core.usd.town_reader import load_town

pytest.importorskip("warp")
from roadtwin_warp_render.renderer import WarpRenderer  # noqa: E402


def _pole_stage(tmp: Path, foot: tuple[float, float]) -> Path:
    """A 30 x 30 m flat driving surface (x 0..30) and one utility pole standing at ``foot``."""
    (tmp / "layers").mkdir()
    pole = make_prototype("utility_pole")
    group = PropGroup("Poles", [pole], np.array([[foot[0], foot[1], 0.0]]), np.array([[1.0, 0, 0, 0]]),
                      np.ones((1, 3)), np.zeros(1, np.int32), "test", "roadside")
    write_props(tmp, "Town", "test", Props([group]))
    road = new_layer(tmp / "layers/road.usda", "Town", "road")
    spec = define_prim(road, "/Town/Road", "Mesh")
    Sdf.AttributeSpec(spec, "roadtwin:segment:kind", Sdf.ValueTypeNames.Token).default = "driving"
    x, y = np.meshgrid(np.linspace(0, 30, 16), np.linspace(-15, 15, 16))
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    a = (np.arange(15)[:, None] * 16 + np.arange(15)[None]).ravel()
    f = np.concatenate([np.column_stack([a, a + 1, a + 17]), np.column_stack([a, a + 17, a + 16])])
    author_mesh_geometry(road, "/Town/Road", v, f)
    road.Save()
    root = new_layer(tmp / "town.usda", "Town", "pole shadow")
    root.subLayerPaths = ["./layers/props.usda", "./layers/road.usda"]
    Sdf.CreatePrimInLayer(root, Sdf.Path("/Town")).specifier = Sdf.SpecifierDef
    root.Save()
    return tmp / "town.usda"


def test_pole_shadow_lands_where_the_sun_says(tmp_path):
    foot = (-0.6, 0.0)                       # on the verge, just off the road's x = 0 edge
    elevation, azimuth = 40.0, 200.0         # sun behind the pole: the shadow falls across the road
    town = load_town(_pole_stage(tmp_path, foot), looks=True)
    assert {m.kind for m in town.props} == {"pole"}
    mesh = build_render_mesh(town)
    cam = Camera(Intrinsics.from_fov(400, 400, 60.0), look_from([12.0, -2.0, 30.0], 0.0, -math.pi / 2))
    params = RenderParams(sun_elevation_deg=elevation, sun_azimuth_deg=azimuth, device="cpu")
    frame = next(iter(WarpRenderer().render(mesh, [cam], params)))

    # world XY of every pixel (a camera looking straight down at the plane z = 0)
    d, o = cam.rays()
    t = -o[2] / d[..., 2]
    world = o[None, None, :2] + d[..., :2] * t[..., None]
    road = frame.semantic == mesh.classes.index("driving")
    lum = frame.rgb.mean(axis=2)
    shadow = road & (lum < 0.5 * np.median(lum[road]))
    assert shadow.sum() > 50

    # closed form: a point at height h falls h / tan(el) from the foot, away from the sun
    el, az = math.radians(elevation), math.radians(azimuth)
    away = -np.array([math.cos(az), math.sin(az)])
    pts = world[shadow] - np.array(foot)
    along = pts @ away
    across = pts @ np.array([-away[1], away[0]])
    tip = 9.0 / math.tan(el)                 # the shaft's top (9 m)
    arm = 8.6 / math.tan(el)                 # the crossarm (8.5..8.6 m), 1.8 m wide
    px = 2 * 30.0 * math.tan(math.radians(30.0)) / 400   # metres per pixel on the road
    on_shaft = np.abs(across) <= 0.14 + 1.5 * px
    on_arm = (np.abs(along - arm) <= 0.25 + 1.5 * px) & (np.abs(across) <= 0.9 + 1.5 * px)
    assert (on_shaft | on_arm).mean() > 0.98, "shadow pixels off the closed-form shadow of the pole"
    assert along.max() == pytest.approx(tip, abs=0.3)
    # the shadow covers the projected line on the road, from the road's edge to the tip
    road_start = max(0.0, (0.0 - foot[0]) / away[0])
    bins = np.arange(road_start + 0.3, tip - 0.3, 0.25)
    hit = np.histogram(along[on_shaft], bins=np.append(bins, tip - 0.3))[0] > 0
    assert hit.mean() > 0.95
    # the pole itself is drawn and labelled (labels follow the nearest surface: occlusion)
    assert (frame.semantic == mesh.classes.index("pole")).sum() > 5
