"""Built-in exporters: a composed town stage -> usdz, glb, obj or ply, road and defects kept apart.

``roadtwin export town.usda --format glb`` (or ``obj``, ``ply``, ``usdz``) writes ``town.glb``
beside the stage unless ``-o`` says otherwise. Every exporter:

- reads what a viewer would draw: each ``UsdGeom.Mesh`` with purpose default/render and not
  invisible (the physics colliders are the road and defect meshes themselves, drawn once), in world space, Z-up
  meters, triangulated (see ``_stage.py``);
- keeps one mesh per prim, named by its prim path (``Town/Roads/east_00_1``,
  ``Town/Defects/D00003/east_00_1``), with the semantic class from ``UsdSemantics`` labels;
- writes atomically (a temporary file in the target's directory, then ``os.replace``; removed on
  error), and turns bad input (missing file, not USD, no renderable meshes) into a one-line
  :class:`roadtwin_core.RoadtwinError` naming the file.

Format details (axes, groups, where the class goes) are in ``meshes.py`` and ``usdz.py``:
glb is rotated to glTF's Y-up, ``(x, y, z) -> (x, z, -y)``, with the class in node/mesh
``extras``; obj and ply stay Z-up; obj has one ``o``/``g`` per prim and an ``.mtl`` beside it;
ply is one mesh with per-face class colour, ``class_id`` and ``prim_id`` (mapped in header
comments); usdz packages every layer and library asset as is.
"""
from roadtwin_core import hookimpl

from .meshes import GlbExporter, ObjExporter, PlyExporter
from .usdz import UsdzExporter

__all__ = ["GlbExporter", "ObjExporter", "PlyExporter", "UsdzExporter"]


@hookimpl
def roadtwin_register_exporters(register):
    register(UsdzExporter())
    register(GlbExporter())
    register(ObjExporter())
    register(PlyExporter())
