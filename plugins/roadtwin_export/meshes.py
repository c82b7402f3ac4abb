"""glb, obj and ply exporters (through trimesh): one mesh per renderable USD Mesh prim.

All three start from :func:`._stage.collect_parts` (world space, Z-up meters, triangles, guide
and proxy purposes skipped) and keep road and defects apart:

- **glb**: one node + mesh per prim, both named by the prim path without the leading ``/``
  (``Town/Roads/east_00_1``, ``Town/Defects/D00003/east_00_1``). glTF is Y-up by spec, so points
  are rotated Z-up -> Y-up, ``(x, y, z) -> (x, z, -y)`` (a proper rotation: winding and
  handedness are kept), baked into the vertices. Units stay meters (glTF's unit). Each node's
  and mesh's ``extras`` hold ``{"class": "road_defect", "labels": ["road_defect", "pothole"],
  "usdPath": "/Town/...", "roadtwin": {...custom roadtwin:* attributes...}}``; the scene's extras
  note the source and the axis conversion. Materials: each mesh carries its prim's bound USD
  material (one glb material per USD material, shared, named like it): baseColorTexture = the
  diffuse texture with texture coordinates from ``primvars:st``, roughness/metallic as constants
  or a metallicRoughness texture built from the roughness map, normalTexture from the normal map.
  So road, defects and markings stay apart (their own nodes and materials). A prim with no bound
  material (a foreign stage) gets its class colour (road grey, road_defect red).
- **obj**: Z-up meters, as in USD. One ``o <prim path>`` (plus a matching ``g``) per prim and a
  ``usemtl <material>`` (the bound USD material's name; the class name and colour when none);
  the ``.mtl`` is written beside the ``.obj`` with the same stem (``town.obj`` + ``town.mtl``),
  with ``map_Kd <material>.png`` and those diffuse textures beside it too. Read it back per prim
  with ``trimesh.load(path, split_objects=True, group_material=False)``; trimesh's default
  groups by material instead.
- **ply**: Z-up meters. PLY has no groups, so it is one mesh (binary little-endian) whose faces
  carry ``red green blue alpha`` (the class colour: road grey, road_defect red) and two integer
  properties: ``class_id`` and ``prim_id``. Header comments map them back: ``comment class
  <id> <name>`` and ``comment prim <id> <prim path>``; ``comment up_axis Z`` and ``comment
  units meters`` state the frame.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image
from pxr import Ar

from roadtwin_core import RoadtwinError
from roadtwin_core.atomic import atomic_files

from ._stage import Look, Part, collect_parts, open_stage

# Z-up -> Y-up for glTF, as a row-vector rotation: (x, y, z) -> (x, z, -y).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0],
                         [0.0, 0.0, -1.0],
                         [0.0, 1.0, 0.0]])

CLASS_IDS = {"unlabelled": 0, "road": 1, "road_defect": 2}
CLASS_COLORS = {"unlabelled": (200, 200, 200, 255), "road": (128, 128, 128, 255),
                "road_defect": (200, 30, 30, 255)}
_OTHER_COLORS = [(60, 120, 200, 255), (60, 170, 90, 255), (220, 170, 40, 255), (150, 80, 180, 255)]


def _class_table(parts: list[Part]) -> tuple[dict[str, int], dict[str, tuple[int, int, int, int]]]:
    """Class -> integer id and colour; road and road_defect fixed, other classes appended."""
    ids = dict(CLASS_IDS)
    colors = dict(CLASS_COLORS)
    for p in parts:
        c = p.semantic_class
        if c not in ids:
            ids[c] = len(ids)
            colors[c] = _OTHER_COLORS[(ids[c] - len(CLASS_IDS)) % len(_OTHER_COLORS)]
    return ids, colors


def _material(cls: str, color: tuple[int, int, int, int]) -> "PBRMaterial":
    from trimesh.visual.material import PBRMaterial  # trimesh imported only when exporting

    return PBRMaterial(name=cls, baseColorFactor=list(color), metallicFactor=0.0, roughnessFactor=0.9,
                       doubleSided=True)


def _image(path: str, mode: str):
    """A texture as a PIL image, read through USD's asset resolver (plain files and usdz members)."""
    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(path))
    if asset is None:
        raise RoadtwinError(f"{path}: texture cannot be read")
    return Image.open(io.BytesIO(bytes(asset.GetBuffer()))).convert(mode)


def _look_material(look: Look, textured: bool) -> "PBRMaterial":
    """glTF metallic-roughness material from a UsdPreviewSurface look; textures only when the
    part has texture coordinates."""
    from trimesh.visual.material import PBRMaterial

    kw = {"name": look.name, "doubleSided": True, "metallicFactor": look.metallic, "roughnessFactor": look.roughness}
    if textured and look.diffuse_file:
        kw["baseColorTexture"] = _image(look.diffuse_file, "RGB")
        kw["baseColorFactor"] = [255, 255, 255, 255]
    else:
        kw["baseColorFactor"] = [int(round(255 * min(max(c, 0.0), 1.0))) for c in look.diffuse_color] + [255]
    if textured and look.roughness_file:
        g = np.asarray(_image(look.roughness_file, "L"))
        rgb = np.stack([np.zeros_like(g), g, np.full_like(g, int(round(255 * look.metallic)))], axis=-1)
        kw.update(metallicRoughnessTexture=Image.fromarray(rgb), roughnessFactor=1.0, metallicFactor=1.0)
    if textured and look.normal_file:
        kw["normalTexture"] = _image(look.normal_file, "RGB")
    return PBRMaterial(**kw)


def _extras(part: Part) -> dict:
    extras = {"class": part.semantic_class, "labels": list(part.labels), "usdPath": part.path,
              "roadtwin": part.attrs}
    if part.look is not None:
        extras["material"] = part.look.path
    return extras


def _scene(parts: list[Part], rotate: np.ndarray | None, with_extras: bool) -> "trimesh.Scene":
    import trimesh
    from trimesh.visual import TextureVisuals

    _, colors = _class_table(parts)
    materials = {c: _material(c, col) for c, col in colors.items()}
    looks: dict[tuple[str, bool], "PBRMaterial"] = {}   # one material object per USD material: stored once
    scene = trimesh.Scene()
    for part in parts:
        v = part.vertices @ rotate if rotate is not None else part.vertices
        extras = _extras(part) if with_extras else {}
        if part.look is not None:
            textured = part.st is not None
            key = (part.look.path, textured)
            if key not in looks:
                looks[key] = _look_material(part.look, textured)
            visual = TextureVisuals(uv=part.st, material=looks[key])
        else:
            visual = TextureVisuals(material=materials[part.semantic_class])
        mesh = trimesh.Trimesh(v, part.faces, process=False, validate=False, visual=visual, metadata=dict(extras))
        scene.add_geometry(mesh, geom_name=part.name, node_name=part.name,
                           metadata=dict(extras) if with_extras else None)
    return scene


def _load(stage_path: Path) -> list[Part]:
    stage_path = Path(stage_path)
    return collect_parts(open_stage(stage_path), stage_path)


class GlbExporter:
    name = "glb"
    suffix = ".glb"
    description = "binary glTF, Y-up meters; one node per USD mesh prim with its material and textures, class in extras"

    def export(self, stage_path: Path, out_path: Path) -> Path:
        stage_path, out_path = Path(stage_path), Path(out_path)
        parts = _load(stage_path)
        scene = _scene(parts, Z_UP_TO_Y_UP, with_extras=True)
        scene.metadata["roadtwin"] = {
            "source": stage_path.name, "units": "meters", "upAxis": "Y",
            "axisConversion": "USD Z-up (x, y, z) -> glTF Y-up (x, z, -y)"}
        data = scene.export(file_type="glb", include_normals=False)
        with atomic_files(out_path) as (tmp,):
            tmp.write_bytes(data)
        return out_path


class ObjExporter:
    name = "obj"
    suffix = ".obj"
    description = "Wavefront OBJ + MTL and diffuse textures beside it, Z-up meters; one object per USD mesh prim"

    def export(self, stage_path: Path, out_path: Path) -> Path:
        from trimesh.exchange.obj import export_obj

        stage_path, out_path = Path(stage_path), Path(out_path)
        parts = _load(stage_path)
        mtl_path = out_path.with_suffix(".mtl")
        if mtl_path == out_path:
            mtl_path = out_path.with_name(out_path.name + ".mtl")
        scene = _scene(parts, None, with_extras=False)
        text, files = export_obj(scene, include_normals=False, include_color=False, include_texture=True,
                                 mtl_name=mtl_path.name, return_texture=True,
                                 header=f"roadtwin export of {stage_path.name}: Z-up, meters")
        # trimesh writes `o <name>` per geometry; add a matching `g` for tools that group by it.
        lines = []
        for line in text.splitlines():
            lines.append(line)
            if line.startswith("o "):
                lines.append("g " + line[2:])
        mtl = files.pop(mtl_path.name, b"")
        textures = {out_path.with_name(name): data for name, data in sorted(files.items())}
        # Textures first, then the .mtl naming them, then the .obj naming the .mtl.
        with atomic_files(*textures, mtl_path, out_path) as tmps:
            for tmp, data in zip(tmps, textures.values()):
                tmp.write_bytes(data if isinstance(data, bytes) else data.encode())
            tmps[-2].write_bytes(mtl if isinstance(mtl, bytes) else mtl.encode())
            tmps[-1].write_text("\n".join(lines) + "\n")
        return out_path


class PlyExporter:
    name = "ply"
    suffix = ".ply"
    description = "binary PLY, Z-up meters; one mesh, per-face class colour, class_id and prim_id"

    def export(self, stage_path: Path, out_path: Path) -> Path:
        stage_path, out_path = Path(stage_path), Path(out_path)
        parts = _load(stage_path)
        ids, colors = _class_table(parts)
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
        vertices = np.concatenate([p.vertices for p in parts])
        faces = np.concatenate([p.faces + off for p, off in zip(parts, offsets)])
        nface = [len(p.faces) for p in parts]
        class_id = np.repeat([ids[p.semantic_class] for p in parts], nface).astype(np.int32)
        prim_id = np.repeat(np.arange(len(parts)), nface).astype(np.int32)
        face_colors = np.asarray([colors[p.semantic_class] for p in parts], dtype=np.uint8)[prim_id]
        import trimesh

        mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False, face_colors=face_colors)
        mesh.face_attributes["class_id"] = class_id
        mesh.face_attributes["prim_id"] = prim_id
        data = mesh.export(file_type="ply", encoding="binary", include_attributes=True)
        comments = [f"roadtwin export of {stage_path.name}", "up_axis Z", "units meters",
                    *(f"class {i} {c}" for c, i in sorted(ids.items(), key=lambda kv: kv[1])),
                    *(f"prim {i} {p.path}" for i, p in enumerate(parts))]
        data = _add_ply_comments(data, comments)
        with atomic_files(out_path) as (tmp,):
            tmp.write_bytes(data)
        return out_path


def _add_ply_comments(data: bytes, comments: list[str]) -> bytes:
    """Insert ``comment`` lines right after the ``format`` line of a PLY header."""
    end = data.index(b"end_header\n")
    header = data[:end].decode("utf-8").split("\n")
    at = next(i for i, line in enumerate(header) if line.startswith("format ")) + 1
    header[at:at] = [f"comment {c}" for c in comments]
    return "\n".join(header).encode("utf-8") + data[end:]
