"""Camera rigs as ``UsdGeom.Camera`` prims: written into a stage's ``layers/cameras.usda`` and
read back as roadtwin cameras, so a stage carries its sensors and any USD tool sees them.

Why a layer of its own: cameras are one concern among the town's layers
(docs/architecture.md#layers-of-a-town-stage: each concern its own layer so a user can mute or
swap it); ``add_rig_cameras`` creates ``layers/cameras.usda`` beside the stage and inserts it as
the strongest sublayer of the stage's root layer.

USD conventions used (UsdGeomCamera docs):

- lens and filmback (``focalLength``, ``horizontalAperture``, ``verticalAperture``) are in
  *tenths of a scene unit*; a stage in metres stores a 36 mm filmback as 0.36. Each rig gets a
  35 mm-equivalent filmback (36 mm wide, the image's aspect high: square pixels) and the focal
  length that gives its field of view, so ``fx = focalLength / horizontalAperture * width``;
- a USD camera looks down its local -Z with +Y up; roadtwin's cameras are OpenCV (x right, y
  down, z forward), so ``usd_to_world = cam_to_world @ diag(1, -1, -1, 1)``;
- ``clippingRange`` in scene units; the image size, mounting height, pitch, stereo baseline and
  the preset's name are ``roadtwin:rig:*`` attributes (USD cameras carry no pixel size).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import RoadtwinError
from .cameras import RIG_PRESETS, Camera, Intrinsics, RigPreset, lane_keep_out, look_from
from .scene import GroundSampler, build_render_mesh, stage_lanes
from .view_sampler import chain_lanes, road_attitude

FILMBACK_WIDTH_MM = 36.0
CLIPPING_RANGE_M = (0.05, 1000.0)
CV_TO_USD = np.diag([1.0, -1.0, -1.0, 1.0])     # OpenCV camera axes <-> USD camera axes (self-inverse)
CAMERAS_LAYER = "layers/cameras.usda"


@dataclass
class StageCamera:
    """A camera prim read back: its path, rig name (``roadtwin:rig:name`` or the prim name),
    pinhole intrinsics, OpenCV cam_to_world and stereo baseline (None = mono)."""

    path: str
    rig: str
    intrinsics: Intrinsics
    cam_to_world: np.ndarray
    baseline_m: float | None = None

    def camera(self) -> Camera:
        return Camera(self.intrinsics, self.cam_to_world)


def rig_preset(name: str) -> RigPreset:
    if name not in RIG_PRESETS:
        raise RoadtwinError(f"unknown rig {name!r} (known: {', '.join(RIG_PRESETS)})")
    return RIG_PRESETS[name]


def lens_tenths(preset: RigPreset, meters_per_unit: float = 1.0) -> dict[str, float]:
    """focalLength / horizontalAperture / verticalAperture of a preset in tenths of a scene unit."""
    to_tenths = 1e-3 / (0.1 * meters_per_unit)                   # mm -> tenths of a scene unit
    hap = FILMBACK_WIDTH_MM
    vap = hap * preset.height / preset.width
    focal = 0.5 * hap / math.tan(math.radians(preset.hfov_deg) / 2)
    return {"focalLength": focal * to_tenths, "horizontalAperture": hap * to_tenths,
            "verticalAperture": vap * to_tenths}


def default_pose(stage_path: str | Path, preset: RigPreset, at_s: float = 20.0) -> np.ndarray:
    """A pose for the rig on the stage's first driving lane (lanes chained), ``at_s`` m along it
    (or further on, clear of a vehicle standing in the lane), the rig's height above the road
    under the wheels, its pitch, looking along the lane."""
    from ..usd.town_reader import load_town   # pxr stays out of render's import (GPU machines have no USD)

    lanes = chain_lanes(stage_lanes(stage_path))
    if not lanes:
        raise RoadtwinError(f"{stage_path}: no driving lane centrelines to place the {preset.name} rig on")
    lane = lanes[0]
    s = float(min(max(at_s, 2.0), max(lane.length - 2.0, 0.0)))
    town = load_town(stage_path)
    keep_out = lane_keep_out(town)
    while not keep_out.clear(lane.at(np.array([s]))[0]) and s + 1.0 <= lane.length - 2.0:
        s += 1.0
    ground = GroundSampler(build_render_mesh(town))
    heading = float(lane.heading(np.array([s]), window=2.0)[0])
    xy = lane.at(np.array([s]))[0]
    z, pitch, roll = road_attitude(ground, xy, heading)
    if not math.isfinite(z):
        raise RoadtwinError(f"{stage_path}: no road under lane {lane.id} at s = {s:.1f} m to place the rig on")
    return look_from((xy[0], xy[1], z + preset.height_m), heading, math.radians(preset.pitch_deg) + pitch, roll)


def write_rig_camera(stage, prim_path: str, preset: RigPreset, cam_to_world: np.ndarray):
    """Define (or redefine) one ``UsdGeom.Camera`` at ``prim_path`` in ``stage``'s edit target."""
    from pxr import Gf, Sdf, UsdGeom

    mpu = UsdGeom.GetStageMetersPerUnit(stage) or 1.0
    cam = UsdGeom.Camera.Define(stage, prim_path)
    lens = lens_tenths(preset, mpu)
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateFocalLengthAttr(lens["focalLength"])
    cam.CreateHorizontalApertureAttr(lens["horizontalAperture"])
    cam.CreateVerticalApertureAttr(lens["verticalAperture"])
    cam.CreateClippingRangeAttr(Gf.Vec2f(CLIPPING_RANGE_M[0] / mpu, CLIPPING_RANGE_M[1] / mpu))
    m = np.asarray(cam_to_world, np.float64) @ CV_TO_USD
    m[:3, 3] /= mpu
    cam.ClearXformOpOrder()
    cam.AddTransformOp().Set(Gf.Matrix4d(m.T.tolist()))        # USD matrices are row-vector (transposed)
    prim = cam.GetPrim()
    attrs = {"name": (Sdf.ValueTypeNames.String, preset.name), "widthPx": (Sdf.ValueTypeNames.Int, preset.width),
             "heightPx": (Sdf.ValueTypeNames.Int, preset.height), "hfovDeg": (Sdf.ValueTypeNames.Double, preset.hfov_deg),
             "mountHeightM": (Sdf.ValueTypeNames.Double, preset.height_m),
             "pitchDeg": (Sdf.ValueTypeNames.Double, preset.pitch_deg),
             "source": (Sdf.ValueTypeNames.String, preset.source)}
    if preset.baseline_m:
        attrs["baselineM"] = (Sdf.ValueTypeNames.Double, preset.baseline_m)
        cam.CreateStereoRoleAttr(UsdGeom.Tokens.left)
    for key, (tp, value) in attrs.items():
        prim.CreateAttribute(f"roadtwin:rig:{key}", tp, custom=True).Set(value)
    return cam


def add_rig_cameras(stage_path: str | Path, rigs: Sequence[str], at_s: float = 20.0,
                    poses: dict[str, np.ndarray] | None = None) -> Path:
    """Write one camera per rig (``/<root>/Cameras/<rig>``) into ``layers/cameras.usda`` beside
    the stage and make it the stage's strongest sublayer. Poses: ``poses[rig]`` (OpenCV
    cam_to_world) or :func:`default_pose`. Cameras of other rigs already there are kept."""
    from pxr import Sdf, Usd, UsdGeom

    stage_path = Path(stage_path)
    if not stage_path.is_file():
        raise RoadtwinError(f"{stage_path}: no such stage")
    presets = [rig_preset(r) for r in rigs]
    if not presets:
        raise RoadtwinError("no rig given (known: " + ", ".join(RIG_PRESETS) + ")")
    stage = Usd.Stage.Open(str(stage_path))
    if stage is None or not stage.GetDefaultPrim():
        raise RoadtwinError(f"{stage_path}: not a USD stage with a defaultPrim")
    root = stage.GetDefaultPrim().GetPath()
    poses = dict(poses or {})
    for p in presets:
        if p.name not in poses:
            poses[p.name] = default_pose(stage_path, p, at_s)
    layer_path = stage_path.parent / CAMERAS_LAYER
    layer_path.parent.mkdir(parents=True, exist_ok=True)
    layer = Sdf.Layer.FindOrOpen(str(layer_path)) if layer_path.exists() else Sdf.Layer.CreateNew(str(layer_path))
    cams = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(cams, UsdGeom.GetStageUpAxis(stage))
    UsdGeom.SetStageMetersPerUnit(cams, UsdGeom.GetStageMetersPerUnit(stage))
    cams.SetMetadata("kilogramsPerUnit", 1.0)
    cams.OverridePrim(root)
    cams.SetDefaultPrim(cams.GetPrimAtPath(root))
    group = UsdGeom.Scope.Define(cams, root.AppendChild("Cameras"))
    group.GetPrim().SetDocumentation("camera rigs (roadtwin rig add); roadtwin render uses them without --views/--poses")
    for p in presets:
        write_rig_camera(cams, str(group.GetPath().AppendChild(p.name)), p, poses[p.name])
    layer.Save()
    root_layer = Sdf.Layer.FindOrOpen(str(stage_path))
    rel = "./" + CAMERAS_LAYER
    if rel not in list(root_layer.subLayerPaths):
        root_layer.subLayerPaths.insert(0, rel)
        root_layer.Save()
    return layer_path


def read_stage_cameras(stage_path: str | Path, size: tuple[int, int] | None = None) -> list[StageCamera]:
    """Every ``UsdGeom.Camera`` of a stage (traversal order) as pinhole cameras. Image size:
    ``size`` when given (the lens is kept: fx scales with the width), else
    ``roadtwin:rig:widthPx/heightPx`` (a camera without either is an error naming it); fx, fy
    from focal length over aperture (same units, so metersPerUnit cancels), principal point at
    the image centre plus the aperture offsets."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(stage_path))
    if stage is None:
        raise RoadtwinError(f"{stage_path}: not a USD stage")
    mpu = UsdGeom.GetStageMetersPerUnit(stage) or 1.0
    out = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Camera):
            continue
        cam = UsdGeom.Camera(prim)
        where = f"{stage_path}: camera {prim.GetPath()}"
        w_attr, h_attr = prim.GetAttribute("roadtwin:rig:widthPx"), prim.GetAttribute("roadtwin:rig:heightPx")
        if size is not None:
            width, height = size
        elif w_attr and w_attr.HasValue() and h_attr and h_attr.HasValue():
            width, height = int(w_attr.Get()), int(h_attr.Get())
        else:
            raise RoadtwinError(f"{where} has no roadtwin:rig:widthPx/heightPx; give --size")
        if str(cam.GetProjectionAttr().Get()) != "perspective":
            raise RoadtwinError(f"{where} is not a perspective camera")
        focal = float(cam.GetFocalLengthAttr().Get())
        hap, vap = float(cam.GetHorizontalApertureAttr().Get()), float(cam.GetVerticalApertureAttr().Get())
        if not (focal > 0 and hap > 0 and vap > 0):
            raise RoadtwinError(f"{where}: focalLength and apertures must be > 0 (got {focal}, {hap}, {vap})")
        fx, fy = focal / hap * width, focal / vap * height
        cx = (width - 1) / 2.0 + float(cam.GetHorizontalApertureOffsetAttr().Get() or 0.0) / hap * width
        cy = (height - 1) / 2.0 - float(cam.GetVerticalApertureOffsetAttr().Get() or 0.0) / vap * height
        intr = Intrinsics(width, height, fx, fy, cx, cy)
        hfov_attr = prim.GetAttribute("roadtwin:rig:hfovDeg")
        if hfov_attr and hfov_attr.HasValue() and cx == (width - 1) / 2.0 and cy == (height - 1) / 2.0:
            # a roadtwin rig: the lens is stored as float32 (USD's camera schema); the double
            # field of view beside it gives the preset's intrinsics exactly when they agree
            exact = Intrinsics.from_fov(width, height, float(hfov_attr.Get()))
            if abs(exact.fx / fx - 1) < 1e-5 and abs(exact.fy / fy - 1) < 1e-5:
                intr = exact
        xf = np.array(cam.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64).T
        xf[:3, 3] *= mpu
        scale = np.linalg.norm(xf[:3, :3], axis=0)
        if not np.allclose(scale, scale[0], rtol=1e-6) or scale[0] <= 0:
            raise RoadtwinError(f"{where}: its transform scales non-uniformly or by zero")
        xf[:3, :3] /= scale[0]
        name_attr = prim.GetAttribute("roadtwin:rig:name")
        rig = str(name_attr.Get()) if name_attr and name_attr.HasValue() else prim.GetName()
        base = prim.GetAttribute("roadtwin:rig:baselineM")
        baseline = float(base.Get()) if base and base.HasValue() else None
        out.append(StageCamera(str(prim.GetPath()), rig, intr, xf @ CV_TO_USD, baseline))
    return out
