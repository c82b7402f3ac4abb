"""The built-in exporters (usdz, glb, obj, ply), checked against the USD stage itself.

A small town is composed once per module; every expectation (mesh count, areas, triangle count,
bounds, defect prims, bound materials, texture coordinates and texture pixels) is computed here
straight from pxr and Pillow, independently of the plugin's reader.
"""
from __future__ import annotations

import json
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy.spatial import cKDTree
from pxr import Ar, Gf, Sdf, Usd, UsdGeom, UsdSemantics, UsdShade, Vt

from roadtwin_core import RoadtwinError, get_plugin_manager
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.town.prop_shapes import PROP_LABELS
from roadtwin_core.usd.town_reader import load_town

ROOT = Path(__file__).resolve().parents[2]
ROADTWIN = Path(sys.executable).with_name("roadtwin")
FORMATS = {"usdz": ".usdz", "glb": ".glb", "obj": ".obj", "ply": ".ply"}


# --------------------------------------------------------------------------- reference from pxr
def usd_reference(stage_path: Path) -> dict:
    """Renderable meshes (Mesh, purpose not guide/proxy, not invisible), world-space triangles."""
    stage = Usd.Stage.Open(str(stage_path))
    meshes = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        img = UsdGeom.Imageable(prim)
        if img.ComputePurpose() in ("guide", "proxy") or img.ComputeVisibility() == "invisible":
            continue
        mesh = UsdGeom.Mesh(prim)
        pts = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64)
        m = np.array(mesh.ComputeLocalToWorldTransform(Usd.TimeCode.Default()))
        pts = pts @ m[:3, :3] + m[3, :3]
        tris = []
        i = 0
        idx = list(mesh.GetFaceVertexIndicesAttr().Get())
        for c in mesh.GetFaceVertexCountsAttr().Get():
            tris += [(idx[i], idx[i + k], idx[i + k + 1]) for k in range(1, c - 1)]
            i += c
        t = pts[np.array(tris)]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
        material = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        diffuse = stage.GetPrimAtPath(material.GetPath().AppendChild("Diffuse"))
        meshes[str(prim.GetPath())] = {
            "points": pts, "triangles": len(tris), "area": area, "material": material.GetPath().name,
            "st": np.array(UsdGeom.PrimvarsAPI(prim).GetPrimvar("st").Get(), dtype=np.float64),
            "diffuse": diffuse.GetAttribute("inputs:file").Get().resolvedPath}
    defects = stage.GetPrimAtPath("/Town/Defects").GetChildren()
    allpts = np.concatenate([m["points"] for m in meshes.values()])
    return {
        "meshes": meshes,
        "names": {p.lstrip("/") for p in meshes},
        "defect_prims": len(defects),
        "defect_meshes": sum("/Defects/" in p for p in meshes),
        "triangles": sum(m["triangles"] for m in meshes.values()),
        "road_area": sum(m["area"] for p, m in meshes.items() if "/Defects/" not in p),
        "defect_area": sum(m["area"] for p, m in meshes.items() if "/Defects/" in p),
        "lo": allpts.min(axis=0), "hi": allpts.max(axis=0),
    }


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(ROADTWIN), *args], capture_output=True, text=True, cwd=ROOT, timeout=120)


@pytest.fixture(scope="module")
def town(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export") / "town"
    # no props: the reference above reads textured road meshes (props: test_glb_draws_the_props_as_instanced)
    return compose(ROOT / "stages/town.usda", out, defects=6, seed=1, preview=False, surface="flat", props="none").town


@pytest.fixture(scope="module")
def ref(town) -> dict:
    r = usd_reference(town)
    assert r["defect_prims"] == 6 and r["defect_meshes"] >= 6
    assert "Town/Collision" not in " ".join(r["names"])  # no collider copies (physics marks these meshes)
    return r


@pytest.fixture(scope="module")
def exported(town, tmp_path_factory) -> dict[str, Path]:
    """Each format once, through the CLI (ply to its default name beside the stage)."""
    outdir = tmp_path_factory.mktemp("exported")
    paths = {}
    for fmt, suffix in FORMATS.items():
        args = ["export", str(town), "--format", fmt]
        target = town.with_suffix(suffix) if fmt == "ply" else outdir / f"town{suffix}"
        if fmt != "ply":
            args += ["-o", str(target)]
        r = cli(*args)
        assert r.returncode == 0, r.stderr
        assert target.is_file()
        paths[fmt] = target
    assert not [p for p in outdir.iterdir() if ".tmp-" in p.name]
    return paths


def _areas(meshes: dict[str, trimesh.Trimesh]) -> tuple[float, float]:
    road = sum(m.area for n, m in meshes.items() if "Defects" not in n)
    defect = sum(m.area for n, m in meshes.items() if "Defects" in n)
    return road, defect


def _check_meshes(meshes: dict[str, trimesh.Trimesh], ref: dict) -> None:
    assert len(meshes) == len(ref["meshes"])
    assert set(meshes) == ref["names"]
    assert sum("Defects" in n for n in meshes) == ref["defect_meshes"]
    road, defect = _areas(meshes)
    assert road == pytest.approx(ref["road_area"], rel=1e-4)
    assert defect == pytest.approx(ref["defect_area"], rel=1e-4)


# --------------------------------------------------------------------------- tests
def test_registered():
    exporters = get_plugin_manager().registry("exporters")
    for fmt, suffix in FORMATS.items():
        assert exporters[fmt].suffix == suffix and exporters[fmt].description


def test_glb(exported, ref):
    scene = trimesh.load(exported["glb"], force="scene")
    # one node per prim; world-space meshes (node transforms applied) keyed by node name
    meshes = {node: scene.geometry[geom].copy().apply_transform(scene.graph[node][0])
              for node in scene.graph.nodes_geometry for geom in [scene.graph[node][1]]}
    _check_meshes(meshes, ref)
    # glTF is Y-up: USD (x, y, z) -> (x, z, -y)
    lo, hi = scene.bounds
    assert [lo[1], hi[1]] == pytest.approx([ref["lo"][2], ref["hi"][2]], abs=1e-5)
    assert [lo[0], hi[0]] == pytest.approx([ref["lo"][0], ref["hi"][0]], abs=1e-5)
    assert [lo[2], hi[2]] == pytest.approx([-ref["hi"][1], -ref["lo"][1]], abs=1e-5)
    # the semantic class travels in node extras (read straight from the JSON chunk)
    data = exported["glb"].read_bytes()
    (n,) = struct.unpack("<I", data[12:16])
    gltf = json.loads(data[20:20 + n])
    classes = {node["name"]: node["extras"]["class"] for node in gltf["nodes"] if "mesh" in node}
    assert {c for name, c in classes.items() if "Defects" in name} == {"road_defect"}
    assert {c for name, c in classes.items() if "/Roads/" in name} == {"road"}
    assert {c for name, c in classes.items() if "/MarkingMeshes/" in name} <= {"lane_marking"}
    # each node's mesh carries its prim's bound USD material, each material is stored once
    used = set()
    for node in gltf["nodes"]:
        if "mesh" in node:
            (primitive,) = gltf["meshes"][node["mesh"]]["primitives"]
            material = gltf["materials"][primitive["material"]]
            assert material["name"] == ref["meshes"]["/" + node["name"]]["material"], node["name"]
            assert "baseColorTexture" in material["pbrMetallicRoughness"] and "TEXCOORD_0" in primitive["attributes"]
            used.add(material["name"])
    assert len(gltf["materials"]) == len(used) == len({m["material"] for m in ref["meshes"].values()}) >= 3
    assert len(gltf["images"]) <= 3 * len(used)     # diffuse, metallicRoughness and normal, each stored once
    # texture coordinates are USD's st, the image is the USD diffuse texture
    for name, mesh in meshes.items():
        want = ref["meshes"]["/" + name]
        assert np.asarray(mesh.visual.uv) == pytest.approx(want["st"], abs=1e-5), name
        got = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
        assert np.array_equal(got, np.asarray(Image.open(want["diffuse"]).convert("RGB"))), name


def test_obj(exported, ref):
    obj = exported["obj"]
    mtl = obj.with_suffix(".mtl")
    assert mtl.is_file() and f"mtllib {mtl.name}" in obj.read_text()
    scene = trimesh.load(obj, force="scene", split_objects=True, group_material=False)
    _check_meshes(dict(scene.geometry), ref)
    lo, hi = scene.bounds  # Z-up kept
    assert lo == pytest.approx(ref["lo"], abs=1e-5) and hi == pytest.approx(ref["hi"], abs=1e-5)
    for name, g in scene.geometry.items():
        want = ref["meshes"]["/" + name]
        assert g.visual.material.name == want["material"], name
        # OBJ readers merge points that share position and uv: match each by position
        _, nearest = cKDTree(want["points"]).query(g.vertices)
        assert np.asarray(g.visual.uv) == pytest.approx(want["st"][nearest], abs=1e-6), name
    # the .mtl names a diffuse texture per material, written beside it with the USD texture's pixels
    maps = {}
    for line in mtl.read_text().splitlines():
        if line.startswith("newmtl "):
            current = line.split()[1]
        elif line.startswith("map_Kd "):
            maps[current] = obj.with_name(line.split()[1])
    diffuse = {m["material"]: m["diffuse"] for m in ref["meshes"].values()}
    assert set(maps) == set(diffuse)
    for name, path in maps.items():
        assert path.is_file(), path
        assert np.array_equal(np.asarray(Image.open(path).convert("RGB")), np.asarray(Image.open(diffuse[name]).convert("RGB")))


def test_ply(exported, ref):
    mesh = trimesh.load(exported["ply"], process=False)
    assert len(mesh.faces) == ref["triangles"]
    assert mesh.area == pytest.approx(ref["road_area"] + ref["defect_area"], rel=1e-4)
    faces = mesh.metadata["_ply_raw"]["face"]["data"]
    header = exported["ply"].read_bytes().split(b"end_header")[0].decode()
    classes = dict(line.split()[2:4][::-1] for line in header.splitlines() if line.startswith("comment class "))
    prims = {int(line.split()[2]): line.split()[3] for line in header.splitlines() if line.startswith("comment prim ")}
    assert len(prims) == len(ref["meshes"])
    defect_faces = np.isin(faces["prim_id"], [i for i, p in prims.items() if "/Defects/" in p])
    assert defect_faces.sum() == sum(m["triangles"] for p, m in ref["meshes"].items() if "/Defects/" in p)
    assert (faces["class_id"][defect_faces] == int(classes["road_defect"])).all()
    road_faces = np.isin(faces["prim_id"], [i for i, p in prims.items() if "/Roads/" in p])
    assert (faces["class_id"][road_faces] == int(classes["road"])).all()
    paint_faces = ~defect_faces & ~road_faces
    assert not paint_faces.any() or (faces["class_id"][paint_faces] == int(classes["lane_marking"])).all()
    assert (mesh.visual.face_colors[defect_faces][:, :3] == [200, 30, 30]).all()
    assert mesh.bounds[0] == pytest.approx(ref["lo"], abs=1e-5)  # Z-up kept


def test_usdz(exported, ref, town):
    stage = Usd.Stage.Open(str(exported["usdz"]))
    assert len(stage.GetPrimAtPath("/Town/Defects").GetChildren()) == ref["defect_prims"]
    rendered = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)
                and UsdGeom.Imageable(p).ComputePurpose() not in ("guide", "proxy")]
    assert len(rendered) == len(ref["meshes"])
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    names = zipfile.ZipFile(exported["usdz"]).namelist()
    assert names[0] == "town.usda" and "layers/defects.usda" in names and "layers/looks.usda" in names
    assert any(n.startswith("library/") for n in names)   # the defect library assets came along
    assert {f"layers/{n}.geom.usdc" for n in ("roads", "defects")} <= set(names)  # and the mesh arrays
    for prim in rendered:
        assert len(UsdGeom.Mesh(prim).GetPointsAttr().Get()) == len(ref["meshes"][str(prim.GetPath())]["points"])
    textures = {f"textures/{p.name}" for p in (town.parent / "textures").iterdir()}
    assert textures and textures <= set(names)             # every texture travels inside the package
    for prim in rendered:                                   # and the bound materials resolve to them
        material = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        assert material.GetPath().name == ref["meshes"][str(prim.GetPath())]["material"]
        file = stage.GetPrimAtPath(material.GetPath().AppendChild("Diffuse")).GetAttribute("inputs:file").Get()
        assert ".usdz[" in file.resolvedPath and Ar.GetResolver().OpenAsset(Ar.ResolvedPath(file.resolvedPath))


# --------------------------------------------------------------------------- bad input
def test_cli_missing_stage(tmp_path):
    r = cli("export", str(tmp_path / "missing.usda"), "--format", "glb")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "missing.usda" in lines[0]


def test_cli_unknown_format(town):
    r = cli("export", str(town), "--format", "stl")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "stl" in lines[0]
    for fmt in FORMATS:
        assert fmt in lines[0]


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_bad_input_leaves_nothing(fmt, tmp_path):
    exporter = get_plugin_manager().get("exporters", fmt)
    out = tmp_path / f"out{FORMATS[fmt]}"
    out.write_bytes(b"earlier")
    bad = tmp_path / "garbage.usda"
    bad.write_text("this is not usd\n")
    empty = tmp_path / "empty.usda"
    stage = Usd.Stage.CreateNew(str(empty))
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Town").GetPrim())
    stage.GetRootLayer().Save()
    for path, words in [(tmp_path / "nope.usda", "no such file"), (bad, "not a USD stage"),
                        (empty, "no renderable meshes")]:
        with pytest.raises(RoadtwinError) as exc:
            exporter.export(path, out)
        msg = str(exc.value)
        assert str(path) in msg and words in msg and "\n" not in msg
    assert out.read_bytes() == b"earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out" + FORMATS[fmt], "garbage.usda", "empty.usda"])


# --------------------------------------------------------------------------- reader details
def test_world_space_purpose_visibility_instancer(tmp_path):
    """Transforms, a Y-up centimetre stage, guide/invisible prims and a PointInstancer."""
    path = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, "Y")
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/W").GetPrim())

    def quad(p: str) -> UsdGeom.Mesh:
        m = UsdGeom.Mesh.Define(stage, p)
        m.CreatePointsAttr(Vt.Vec3fArray([(0, 0, 0), (100, 0, 0), (100, 0, 100), (0, 0, 100)]))
        m.CreateFaceVertexCountsAttr([4])
        m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        return m

    moved = quad("/W/Moved")
    moved.AddTranslateOp().Set(Gf.Vec3d(500, 0, 0))        # 5 m along x
    UsdSemantics.LabelsAPI.Apply(moved.GetPrim(), "class").CreateLabelsAttr().Set(["road_defect", "pothole"])
    quad("/W/Guide").CreatePurposeAttr("guide")
    quad("/W/Hidden").CreateVisibilityAttr("invisible")
    pi = UsdGeom.PointInstancer.Define(stage, "/W/Inst")
    quad("/W/Inst/Protos/Q")
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/W/Inst/Protos/Q")])
    pi.CreateProtoIndicesAttr([0, 0, 0])
    pi.CreatePositionsAttr(Vt.Vec3fArray([(0, 1000, 0), (0, 2000, 0), (0, 3000, 0)]))  # 10, 20, 30 m up
    stage.GetRootLayer().Save()

    out = tmp_path / "scene.ply"
    get_plugin_manager().get("exporters", "ply").export(path, out)
    mesh = trimesh.load(out, process=False)
    header = out.read_bytes().split(b"end_header")[0].decode()
    prims = [line.split()[3] for line in header.splitlines() if line.startswith("comment prim ")]
    assert sorted(prims) == sorted(["/W/Moved", *(f"/W/Inst/instance_{i:05d}/Q" for i in range(3))])
    assert len(mesh.faces) == 8 and mesh.area == pytest.approx(4.0)    # four 1 m x 1 m quads
    # Y-up centimetres -> Z-up metres: (x, y, z) cm -> (x, -z, y) / 100
    assert mesh.bounds[0] == pytest.approx([0, -1, 0]) and mesh.bounds[1] == pytest.approx([6, 0, 30])
    faces = mesh.metadata["_ply_raw"]["face"]["data"]
    moved_faces = faces["prim_id"] == prims.index("/W/Moved")
    assert (mesh.triangles_center[moved_faces][:, 0] > 5).all()
    classes = dict(line.split()[2:4][::-1] for line in header.splitlines() if line.startswith("comment class "))
    assert (faces["class_id"][moved_faces] == int(classes["road_defect"])).all()
    # the winding follows the (proper) axis rotation: the quads face -y in Y-up USD, -z here
    assert (mesh.face_normals[:, 2] < -0.99).all()


def test_glb_draws_the_props_as_instanced(tmp_path):
    """A town with its roadside world (layers/props.usda, PointInstancers): the glb has one node
    per instance part, with its class, and as many prop triangles as load_town draws."""
    town = compose(ROOT / "stages/town.usda", tmp_path / "town", defects=2, seed=1, preview=False, surface="flat",
                   executor="serial").town
    out = tmp_path / "town.glb"
    get_plugin_manager().get("exporters", "glb").export(town, out)
    data = out.read_bytes()
    (n,) = struct.unpack("<I", data[12:16])
    gltf = json.loads(data[20:20 + n])
    triangles = {}
    for node in gltf["nodes"]:
        if "mesh" in node and node["extras"]["class"] in PROP_LABELS:
            (primitive,) = gltf["meshes"][node["mesh"]]["primitives"]
            cls = node["extras"]["class"]
            triangles[cls] = triangles.get(cls, 0) + gltf["accessors"][primitive["indices"]]["count"] // 3
    want = {}
    for m in load_town(town).props:
        want[m.kind] = want.get(m.kind, 0) + len(m.faces)
    assert triangles == want and {"vegetation", "vehicle", "pole", "terrain"} <= set(want)
