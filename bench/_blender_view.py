"""Render cameras of a roadtwin stage in Blender (Cycles, CPU): what another tool sees.

Runs inside Blender's Python (``pip install bpy`` in a separate venv; it needs CPython 3.11):

    BPY_PYTHON bench/_blender_view.py STAGE.usda VIEW.json OUT.png [SAMPLES]

VIEW.json holds the camera as roadtwin writes it (OpenCV convention: ``cam_to_world`` 4x4 with
columns x right, y down, z forward; pinhole fx, fy, cx, cy, width, height) and the sun direction
(unit vector towards the sun, world Z up); or a list of such views, rendered from one import to
OUT-0.png, OUT-1.png, ... Nothing here imports roadtwin: Blender reads only the USD stage (its
materials, textures, st and point instancers) through its own importer. Prints one JSON line:
Blender's version, meshes, materials and the point instancers with their instance counts.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import bpy
import mathutils


def main(stage: str, view_json: str, out_png: str, samples: int = 32) -> None:
    views = json.load(open(view_json))
    if isinstance(views, dict):
        views, outs = [views], [out_png]
    else:
        out = Path(out_png)
        outs = [str(out.with_name(f"{out.stem}-{k}{out.suffix}")) for k in range(len(views))]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=stage, import_guide=False, import_proxy=False, import_render=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "PNG"
    for view, png in zip(views, outs):
        place_camera(scene, view)
        light(scene, view)
        scene.render.filepath = png
        bpy.ops.render.render(write_still=True)
    mats = sorted({s.material.name for o in scene.objects if o.type == "MESH" for s in o.material_slots if s.material})
    print(json.dumps({"blender": bpy.app.version_string, "meshes": sum(o.type == "MESH" for o in scene.objects),
                      "materials": mats, "instancers": instancers(scene)}))


def place_camera(scene, view: dict) -> None:
    w, h = int(view["width"]), int(view["height"])
    cam_data = bpy.data.cameras.new("roadtwin_view")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_data.lens = view["fx"] * 36.0 / w
    # principal point offset, in units of the larger image side (Blender's shift convention)
    cam_data.shift_x = -(view["cx"] - (w - 1) / 2) / max(w, h)
    cam_data.shift_y = (view["cy"] - (h - 1) / 2) / max(w, h)
    cam_data.clip_start, cam_data.clip_end = 0.05, 2000.0
    cam = bpy.data.objects.new("roadtwin_view", cam_data)
    scene.collection.objects.link(cam)
    m = mathutils.Matrix(view["cam_to_world"])
    # OpenCV camera (x right, y down, z forward) -> Blender camera (x right, y up, looks down -z)
    flip = mathutils.Matrix(((1, 0, 0, 0), (0, -1, 0, 0), (0, 0, -1, 0), (0, 0, 0, 1)))
    cam.matrix_world = m @ flip
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100


def light(scene, view: dict) -> None:
    """One sun (the view's direction) and a uniform sky; replaces those of an earlier view."""
    for obj in [o for o in scene.objects if o.get("roadtwin_light")]:
        bpy.data.objects.remove(obj)
    sun_dir = mathutils.Vector(view["sun_dir"]).normalized()
    sun_data = bpy.data.lights.new("sun", type="SUN")
    sun_data.energy = float(view.get("sun_strength", 4.0))
    sun_data.angle = math.radians(0.6)
    sun = bpy.data.objects.new("sun", sun_data)
    sun["roadtwin_light"] = True
    sun.rotation_euler = sun_dir.to_track_quat("Z", "Y").to_euler()  # light shines along -Z of the object
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs[0].default_value = (*view.get("sky_rgb", (0.45, 0.6, 0.85)), 1.0)
    bg.inputs[1].default_value = float(view.get("sky_strength", 0.8))
    scene.world = world


def instancers(scene) -> dict:
    """UsdGeom.PointInstancers as Blender imports them (a point cloud whose geometry nodes put
    the prototypes on its points): name -> number of instances."""
    return {o.name: len(o.data.points) for o in scene.objects
            if o.type == "POINTCLOUD" and any(m.type == "NODES" for m in o.modifiers)}


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    main(args[0], args[1], args[2], *(int(a) for a in args[3:4]))
