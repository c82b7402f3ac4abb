"""Looks and lane markings of a composed stage, checked with pxr, shapely and trimesh alone.

A small hand-made layout (a two-lane street with a sidewalk, markings of every painted kind and
a kerb) gets pinned defects across two markings and is composed once per module on a rough road.
Expectations come from closed forms (dash stations, st of a straight lane) or are computed here
independently of roadtwin's code (footprints from the baked defect meshes, road heights by
trimesh ray casts on the roads layer).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import shapely
import triangle
from pxr import Kind, Usd, UsdGeom, UsdSemantics, UsdShade

import roadtwin_core.apps.compose.run as compose_module
from roadtwin_core import ComposeRules, FixedDefect, LaneMarking, MergedSegment, RoadSegment, TownLayout
from roadtwin_core.looks import ROAD_MATERIAL_VARIANTS, ST_TILE_M, MaterialSpec, write_textures
from roadtwin_core.town.markings import build_markings
from roadtwin_core.usd import read_layout, validate_stage, write_layout

ROOT = "/Town"
LENGTH = 30.0
CENTRE = dict(width_m=0.12, dash_m=3.0, gap_m=6.0, phase_m=1.0)   # dashes [1,4] [10,13] [19,22] [28,30]


def _strip(x0, x1, y0, y1, step=2.5):
    xs = np.linspace(x0, x1, int(round((x1 - x0) / step)) + 1)
    poly = np.concatenate([np.column_stack([xs, np.full_like(xs, y0)]), np.column_stack([xs[::-1], np.full_like(xs, y1)])])
    n = len(poly)
    t = triangle.triangulate({"vertices": poly, "segments": np.column_stack([np.arange(n), (np.arange(n) + 1) % n])}, "p")
    return t["vertices"], t["triangles"]


def lanes_layout() -> TownLayout:
    """Lane y < 0 travels +x, lane y > 0 travels -x (right-hand traffic), sidewalk above."""
    segs = []
    for i, (x0, x1) in enumerate([(0.0, 15.0), (15.0, LENGTH)]):
        segs.append(RoadSegment(f"east_{i}", "driving", *_strip(x0, x1, -3.5, 0.0), np.array([[x0, -1.75], [x1, -1.75]])))
        segs.append(RoadSegment(f"west_{i}", "driving", *_strip(x0, x1, 0.0, 3.5), np.array([[x1, 1.75], [x0, 1.75]])))
    segs.append(RoadSegment("walk", "sidewalk", *_strip(0.0, LENGTH, 3.5, 5.5)))
    markings = [
        LaneMarking("centre", "broken", "yellow", points=[[0, 0], [LENGTH, 0]], **CENTRE),
        LaneMarking("edge_east", "solid", "white", 0.15, [[0, -3.2], [LENGTH, -3.2]]),
        LaneMarking("edge_west", "solid_broken", "white", 0.1, [[LENGTH, 3.2], [0, 3.2]], dash_m=3.0, gap_m=3.0,
                    spacing_m=0.25),
        LaneMarking("dots", "botts_dots", "white", 0.1, [[2.0, -1.0], [8.5, -1.0]], dash_m=0.1, gap_m=1.1),
        LaneMarking("kerb", "curb", "white", 0.15, [[0, 3.5], [LENGTH, 3.5]]),
    ]
    pothole = {"radius_m": 0.3, "depth_m": 0.06, "elongation": 1.0, "irregularity": 0.08, "roughness_m": 0.003}
    fixed = [FixedDefect("on_centre_dash", "pothole", pothole, 11.5, 0.0, seed=1),      # splits dash [10, 13]
             FixedDefect("on_edge", "pothole", pothole, 20.0, -2.95, seed=2),          # cuts the east edge line
             FixedDefect("crack", "crack", {"extent_m": 1.2}, 6.0, -2.0, seed=3)]
    rules = ComposeRules(defect_count=0, seed=3, surface="iso8608:D:0.1", edge_margin_m=0.05)
    return TownLayout("Town", segs, rules, fixed=fixed, markings=markings)


def _with_maps(real):
    """The texture generator, plus roughness and normal maps on one material if it wrote none
    (so the full shading network is exercised and validated)."""
    def write(folder, seed=0):
        specs = real(folder, seed)
        if not any(s.normal for s in specs.values()):
            from PIL import Image

            folder = Path(folder)
            Image.fromarray(np.full((8, 8), 200, np.uint8)).save(folder / "asphalt_worn_roughness.png")
            Image.fromarray(np.tile(np.array([128, 128, 255], np.uint8), (8, 8, 1))).save(folder / "asphalt_worn_normal.png")
            old = specs["asphalt_worn"]
            specs["asphalt_worn"] = MaterialSpec(old.name, old.diffuse, "asphalt_worn_roughness.png",
                                                 normal="asphalt_worn_normal.png")
        return specs
    return write


@pytest.fixture(scope="module")
def layout() -> TownLayout:
    return lanes_layout()


@pytest.fixture(scope="module")
def out(layout, tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("looks")
    path = base / "lanes.usda"
    write_layout(layout, path)
    with pytest.MonkeyPatch.context() as mp:
        if not read_layout(path).markings:  # until the layout file carries markings
            def read_with_markings(p):
                lay = read_layout(p)
                lay.markings = layout.markings
                return lay
            mp.setattr(compose_module, "read_layout", read_with_markings)
        compose_module.compose(path, base / "out", preview=False, texture_writer=_with_maps(write_textures))
    return base / "out"


@pytest.fixture(scope="module")
def stage(out) -> Usd.Stage:
    return Usd.Stage.Open(str(out / "town.usda"))


def rendered_meshes(stage: Usd.Stage) -> list[Usd.Prim]:
    """The road, defect and marking meshes (the props, under /<root>/Props, have constant colours)."""
    return [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)
            and UsdGeom.Imageable(p).ComputePurpose() not in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)
            and not str(p.GetPath()).startswith(f"{ROOT}/Props/")]


def points_faces(prim: Usd.Prim) -> tuple[np.ndarray, np.ndarray]:
    m = UsdGeom.Mesh(prim)
    pts = np.asarray(m.GetPointsAttr().Get(), dtype=np.float64)
    assert set(m.GetFaceVertexCountsAttr().Get()) == {3}
    return pts, np.asarray(m.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)


def st_of(prim: Usd.Prim) -> np.ndarray:
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    assert pv and pv.GetInterpolation() == UsdGeom.Tokens.vertex, prim.GetPath()
    assert pv.GetTypeName() == "texCoord2f[]", prim.GetPath()
    return np.asarray(pv.Get(), dtype=np.float64)


def marking_prims(stage: Usd.Stage) -> dict[str, Usd.Prim]:
    return {p.GetName(): p for p in stage.GetPrimAtPath(f"{ROOT}/MarkingMeshes").GetChildren()}


def xy_union(pts: np.ndarray, faces: np.ndarray):
    return shapely.union_all(shapely.polygons(pts[faces][:, :, :2]))


# --------------------------------------------------------------------------- materials
def _texture_files(shader: UsdShade.Shader, seen=None) -> list[str]:
    """Resolved files of every UsdUVTexture feeding ``shader``, walking the connections."""
    seen = set() if seen is None else seen
    files = []
    for inp in shader.GetInputs():
        for src in inp.GetConnectedSources()[0]:
            up = UsdShade.Shader(src.source.GetPrim())
            if up.GetPath() in seen:
                continue
            seen.add(up.GetPath())
            if up.GetIdAttr().Get() == "UsdUVTexture":
                asset = up.GetInput("file").Get()
                files.append(asset.resolvedPath or "")
            files += _texture_files(up, seen)
    return files


def test_every_rendered_mesh_has_a_textured_preview_surface(stage):
    groups = {"Roads": 0, "Defects": 0, "MarkingMeshes": 0}
    for prim in rendered_meshes(stage):
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        assert material, f"{prim.GetPath()}: no bound material"
        shader, _, _ = material.ComputeSurfaceSource()
        assert shader and shader.GetIdAttr().Get() == "UsdPreviewSurface", prim.GetPath()
        diffuse = shader.GetInput("diffuseColor").GetConnectedSources()[0]
        assert diffuse, f"{material.GetPath()}: diffuseColor is not textured"
        files = _texture_files(shader)
        assert files and all(f and Path(f).is_file() for f in files), (material.GetPath(), files)
        assert len(st_of(prim)) == len(UsdGeom.Mesh(prim).GetPointsAttr().Get()), prim.GetPath()
        groups[str(prim.GetPath()).split("/")[2]] += 1
    assert groups["Roads"] == 5 and groups["Defects"] >= 3 and groups["MarkingMeshes"] == 4, groups


def test_full_network_with_roughness_and_normal_maps(stage):
    mat = UsdShade.Material(stage.GetPrimAtPath(f"{ROOT}/Looks/asphalt_worn"))
    surface = UsdShade.Shader(stage.GetPrimAtPath(f"{ROOT}/Looks/asphalt_worn/PreviewSurface"))
    assert mat.ComputeSurfaceSource()[0].GetPath() == surface.GetPath()
    for name, output, space in [("diffuseColor", "rgb", "sRGB"), ("roughness", "r", "raw"), ("normal", "rgb", "raw")]:
        (src,), _ = surface.GetInput(name).GetConnectedSources()
        tex = UsdShade.Shader(src.source.GetPrim())
        assert src.sourceName == output and tex.GetIdAttr().Get() == "UsdUVTexture", name
        assert tex.GetInput("sourceColorSpace").Get() == space
        assert tex.GetInput("wrapS").Get() == "repeat" and tex.GetInput("wrapT").Get() == "repeat"
        (st,), _ = tex.GetInput("st").GetConnectedSources()
        reader = UsdShade.Shader(st.source.GetPrim())
        assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float2" and reader.GetInput("varname").Get() == "st"
    normal = UsdShade.Shader(stage.GetPrimAtPath(f"{ROOT}/Looks/asphalt_worn/Normal"))
    assert tuple(normal.GetInput("scale").Get()) == (2, 2, 2, 1)
    assert tuple(normal.GetInput("bias").Get()) == (-1, -1, -1, 0)


def test_zero_validation_errors_and_summary(out, stage):
    errors = [f for f in validate_stage(out / "town.usda") if f.severity == "Error"]
    assert not errors, errors[:3]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["markings"] == 4                       # the curb draws nothing
    assert summary["materials"] == len(stage.GetPrimAtPath(f"{ROOT}/Looks").GetChildren()) >= 10


def test_road_material_variant_switches_driving_surfaces(stage):
    seg = stage.GetPrimAtPath(f"{ROOT}/Roads/east_0")
    vset = stage.GetPrimAtPath(ROOT).GetVariantSets().GetVariantSet("roadMaterial")
    assert vset.GetVariantSelection() == "asphalt"
    assert sorted(vset.GetVariantNames()) == sorted(ROAD_MATERIAL_VARIANTS)
    for variant, material in ROAD_MATERIAL_VARIANTS.items():
        vset.SetVariantSelection(variant)
        bound, _ = UsdShade.MaterialBindingAPI(seg).ComputeBoundMaterial()
        assert bound.GetPath().name == material, variant
    walk, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(f"{ROOT}/Roads/walk")).ComputeBoundMaterial()
    assert walk.GetPath().name == "pavers"       # sidewalks do not follow the road variant
    vset.SetVariantSelection("asphalt")


def test_defects_and_markings_bound_by_type_and_colour(stage):
    def bound(path):
        return UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(path)).ComputeBoundMaterial()[0].GetPath().name

    assert bound(f"{ROOT}/MarkingMeshes/centre") == "paint_yellow"
    assert bound(f"{ROOT}/MarkingMeshes/edge_east") == "paint_white"
    for d in stage.GetPrimAtPath(f"{ROOT}/Defects").GetChildren():
        want = {"pothole": "pothole", "crack": "crack"}[d.GetAttribute("roadtwin:defect:type").Get()]
        for piece in d.GetChildren():
            assert bound(piece.GetPath()) == want


# --------------------------------------------------------------------------- st
def test_lane_aligned_st_on_driving_segments(stage):
    """Straight lanes: u = distance along travel / tile, v = 0.5 + left offset / tile, exactly."""
    for name, x0, sign in [("east_0", 0.0, 1), ("east_1", 15.0, 1), ("west_0", 15.0, -1), ("west_1", LENGTH, -1)]:
        prim = stage.GetPrimAtPath(f"{ROOT}/Roads/{name}")
        pts, _ = points_faces(prim)
        st = st_of(prim)
        centre_y = -1.75 * sign
        assert st[:, 0] == pytest.approx(sign * (pts[:, 0] - x0) / ST_TILE_M, abs=1e-5), name
        assert st[:, 1] == pytest.approx(0.5 + sign * (pts[:, 1] - centre_y) / ST_TILE_M, abs=1e-5), name
    # World-planar elsewhere: sidewalk, defects, markings.
    for path in [f"{ROOT}/Roads/walk", f"{ROOT}/MarkingMeshes/centre",
                 *(str(c.GetPath()) for d in stage.GetPrimAtPath(f"{ROOT}/Defects").GetChildren() for c in d.GetChildren())]:
        prim = stage.GetPrimAtPath(path)
        assert st_of(prim) == pytest.approx(points_faces(prim)[0][:, :2] / ST_TILE_M, abs=1e-5), path


# --------------------------------------------------------------------------- markings
def test_marking_prims_labels_and_attributes(stage, layout):
    group = stage.GetPrimAtPath(f"{ROOT}/MarkingMeshes")
    assert Usd.ModelAPI(group).GetKind() == Kind.Tokens.group
    prims = marking_prims(stage)
    assert sorted(prims) == ["centre", "dots", "edge_east", "edge_west"]
    query = UsdSemantics.LabelsQuery("class", Usd.TimeCode.Default())
    by_id = {m.id: m for m in layout.markings}
    for name, prim in prims.items():
        assert Usd.ModelAPI(prim).GetKind() == Kind.Tokens.component
        assert prim.GetAttribute("roadtwin:marking:type").Get() == by_id[name].marking_type
        assert prim.GetAttribute("roadtwin:marking:color").Get() == by_id[name].color
        assert set(query.ComputeUniqueInheritedLabels(prim)) == {"lane_marking", by_id[name].marking_type}
        own = UsdSemantics.LabelsAPI(prim, "class").GetLabelsAttr().Get()
        assert list(own) == ["lane_marking", by_id[name].marking_type]


def defect_footprints(stage: Usd.Stage):
    """Each defect's area as the XY union of its baked triangles (the paint must be gone there)."""
    out = []
    for d in stage.GetPrimAtPath(f"{ROOT}/Defects").GetChildren():
        out.append(shapely.union_all([xy_union(*points_faces(c)) for c in d.GetChildren()]))
    return out


def test_no_marking_vertex_inside_a_defect(stage):
    holes = defect_footprints(stage)
    assert len(holes) == 3
    crossed = 0
    for name, prim in marking_prims(stage).items():
        pts, faces = points_faces(prim)
        paint = xy_union(pts, faces)
        for hole in holes:
            assert not shapely.contains_xy(hole.buffer(0.01), pts[:, 0], pts[:, 1]).any(), name
            assert paint.intersection(hole).area < 1e-6, name
            crossed += paint.distance(hole) < 0.05
    assert crossed >= 2   # the pinned potholes sit on the centre dash and the east edge line


def test_cut_dash_and_broken_line_geometry(stage):
    """Centre line: dashes [1,4] [10,13] [19,22] [28,30]; the pothole at x 11.5 splits the second."""
    pts, faces = points_faces(marking_prims(stage)["centre"])
    pieces = sorted(xy_union(pts, faces).geoms, key=lambda g: g.bounds[0])
    starts = [round(g.bounds[0], 3) for g in pieces]
    assert len(pieces) == 5
    assert [starts[0], starts[1], starts[3], starts[4]] == [1.0, 10.0, 19.0, 28.0]
    assert pieces[1].bounds[2] < 11.5 - 0.3 < 11.5 + 0.3 < pieces[2].bounds[0]
    assert pieces[4].bounds[2] == pytest.approx(LENGTH, abs=1e-6)
    for g in pieces:
        assert g.bounds[3] - g.bounds[1] == pytest.approx(CENTRE["width_m"], abs=1e-6)
    # solid_broken, travelling -x: solid on the left of travel (y 3.2 - 0.125), broken 0.25 m right of it
    pts, faces = points_faces(marking_prims(stage)["edge_west"])
    paint = xy_union(pts, faces)
    solid = [g for g in paint.geoms if g.bounds[3] < 3.2]
    broken = [g for g in paint.geoms if g.bounds[1] > 3.2]
    assert len(solid) == 1 and solid[0].area == pytest.approx(LENGTH * 0.1, rel=1e-6)
    assert solid[0].centroid.y == pytest.approx(3.075, abs=1e-6)
    assert len(broken) == 5 and sum(g.area for g in broken) == pytest.approx(5 * 3.0 * 0.1, rel=1e-6)
    # botts dots every 1.2 m from x 2 to 8.5: 6 discs of 0.1 m
    pts, faces = points_faces(marking_prims(stage)["dots"])
    dots = xy_union(pts, faces).geoms
    assert len(dots) == 6
    assert sorted(round(g.centroid.x, 3) for g in dots) == pytest.approx([2.0 + 1.2 * k for k in range(6)])
    assert all(g.area == pytest.approx(math.pi * 0.05 ** 2, rel=0.1) for g in dots)


def test_markings_drape_a_few_mm_above_the_road(stage):
    """Road heights from matplotlib's triangle finder + linear interpolation on each road and
    defect mesh of the stage (the highest surface under a point wins)."""
    from matplotlib.tri import LinearTriInterpolator, Triangulation

    surfaces = []
    for p in rendered_meshes(stage):
        if "/MarkingMeshes/" not in str(p.GetPath()):
            pts, faces = points_faces(p)
            surfaces.append(LinearTriInterpolator(Triangulation(pts[:, 0], pts[:, 1], faces), pts[:, 2]))
    road_z = np.concatenate([points_faces(p)[0][:, 2] for p in rendered_meshes(stage) if "/Roads/" in str(p.GetPath())])
    assert np.ptp(road_z) > 0.02      # the road is rough: draping matters

    def ground(xy):
        z = np.full(len(xy), -np.inf)
        for f in surfaces:
            v = f(xy[:, 0], xy[:, 1])
            z = np.where(np.ma.getmaskarray(v), z, np.maximum(z, np.ma.getdata(v)))
        return z

    for name, prim in marking_prims(stage).items():
        pts, faces = points_faces(prim)
        lift = pts[:, 2] - ground(pts[:, :2])
        assert lift == pytest.approx(0.005, abs=1e-4), name          # every vertex 5 mm up
        # Between vertices too: each paint triangle lies on one road triangle (the road's edges
        # are imprinted), so the paint never dips under a rough road or a defect rim.
        centres = pts[faces].mean(axis=1)
        lift = centres[:, 2] - ground(centres[:, :2])
        assert lift == pytest.approx(0.005, abs=2e-4), (name, lift.min(), lift.max())


def test_broken_line_closed_form_on_a_flat_road():
    """Dash count and lengths of a straight broken line: n = ceil((L - phase) / (dash + gap)),
    dash k spans [phase + k pitch, min(phase + k pitch + dash, L)]."""
    L, dash, gap, phase, width = 40.0, 3.0, 6.0, 1.5, 0.15
    v, f = _strip(-1.0, L + 1.0, -2.0, 2.0)
    seg = RoadSegment("s", "driving", v, f)
    merged = MergedSegment("s", np.column_stack([v, np.full(len(v), 0.25)]), f, np.full(len(f), -1))
    m = LaneMarking("c", "broken", "white", width, [[0, 0], [L, 0]], dash_m=dash, gap_m=gap, phase_m=phase)
    (mesh,) = build_markings([m], [seg], [merged], [])
    pieces = sorted(xy_union(mesh.vertices, mesh.faces).geoms, key=lambda g: g.bounds[0])
    n = math.ceil((L - phase) / (dash + gap))
    starts = phase + (dash + gap) * np.arange(n)
    lengths = np.minimum(dash, L - starts)
    assert len(pieces) == n == 5
    assert [g.bounds[0] for g in pieces] == pytest.approx(starts)
    assert [g.bounds[2] - g.bounds[0] for g in pieces] == pytest.approx(lengths)
    assert [g.area for g in pieces] == pytest.approx(lengths * width)
    assert mesh.vertices[:, 2] == pytest.approx(0.255)
    edges = np.linalg.norm(mesh.vertices[mesh.faces][:, [1, 2, 0]] - mesh.vertices[mesh.faces], axis=-1)
    assert edges.max() <= math.hypot(0.5, width) + 1e-9     # dense enough to follow the road's elevation


def test_glb_export_carries_roughness_and_normal_maps(out, tmp_path):
    """glTF metallicRoughness texture: G = the USD roughness map, B = metallic; normalTexture = the
    USD normal map (read back from the glb's embedded images)."""
    import io
    import struct

    from PIL import Image

    from roadtwin_core import get_plugin_manager

    glb = get_plugin_manager().get("exporters", "glb").export(out / "town.usda", tmp_path / "town.glb")
    data = glb.read_bytes()
    (n,) = struct.unpack("<I", data[12:16])
    gltf = json.loads(data[20:20 + n])
    binary = data[20 + n + 8:]

    def image(texture_index):
        view = gltf["bufferViews"][gltf["images"][gltf["textures"][texture_index]["source"]]["bufferView"]]
        start = view.get("byteOffset", 0)
        return np.asarray(Image.open(io.BytesIO(binary[start:start + view["byteLength"]])))

    (mat,) = [m for m in gltf["materials"] if m["name"] == "asphalt_worn"]
    pbr = mat["pbrMetallicRoughness"]
    stage = Usd.Stage.Open(str(out / "town.usda"))

    def usd_texture(shader, mode):
        asset = stage.GetPrimAtPath(f"{ROOT}/Looks/asphalt_worn/{shader}").GetAttribute("inputs:file").Get()
        return np.asarray(Image.open(asset.resolvedPath).convert(mode))

    metallic = stage.GetPrimAtPath(f"{ROOT}/Looks/asphalt_worn/PreviewSurface").GetAttribute("inputs:metallic").Get()
    rough = image(pbr["metallicRoughnessTexture"]["index"])
    assert np.array_equal(rough[..., 1], usd_texture("Roughness", "L"))
    assert (rough[..., 2] == round(255 * metallic)).all()
    assert np.array_equal(image(mat["normalTexture"]["index"])[..., :3], usd_texture("Normal", "RGB"))
    names = {m["name"] for m in gltf["materials"]}
    assert {"paint_yellow", "paint_white", "pothole", "crack"} <= names


def test_a_line_listed_twice_is_painted_once():
    """Maps list some lines twice (CARLA's paired junction roads on one reference line): one
    mesh, not two coincident ones; a crossing line of the same colour and a coincident line of
    another colour are kept."""
    v, f = _strip(-1.0, 21.0, -3.0, 3.0)
    seg = RoadSegment("s", "driving", v, f)
    merged = MergedSegment("s", np.column_stack([v, np.zeros(len(v))]), f, np.full(len(f), -1))
    a = LaneMarking("a", "solid", "white", 0.12, [[0, 0], [20, 0]])
    twice = LaneMarking("a_again", "solid", "white", 0.12, [[20, 0], [0, 0]])        # reversed
    cross = LaneMarking("cross", "solid", "white", 0.12, [[10, -2.5], [10, 2.5]])
    yellow = LaneMarking("y", "solid", "yellow", 0.12, [[0, 0], [20, 0]])
    meshes = build_markings([a, twice, cross, yellow], [seg], [merged], [])
    assert [m.id for m in meshes] == ["a", "cross", "y"]
