"""plan's USD output: a layer over the town with each path and its wheel tracks as curves."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
from pxr import Sdf, UsdGeom, Vt

from ...planning import Footprint, GridMap, PlanResult, resample_by_length
from ...usd.stage import new_stage, set_attrs, set_kind
from .plots import COLOURS


def write_path_layer(path: Path, town_ref: str, root_name: str, results: Sequence[PlanResult], grid: GridMap,
                     vehicle: Footprint, lift_m: float = 0.05) -> Path:
    """A USD layer (Z up, metres, defaultPrim) that sublayers the town stage (``town_ref``,
    relative to the layer or absolute) and adds, per result, an Xform
    ``/<root>/Plans/<planner>_<collision>`` carrying the metrics as ``roadtwin:plan:*``
    attributes, with two linear ``BasisCurves``: ``Path`` (the rear-axle path) and
    ``WheelTracks`` (the four wheel contact centres). z = road height + ``lift_m``, so the curves
    are drawn on the road rather than inside it."""
    path = Path(path)
    stage = new_stage(path, root_name, "roadtwin planned path(s) over " + town_ref)
    stage.GetRootLayer().subLayerPaths = [town_ref]
    stage.OverridePrim(Sdf.Path(f"/{root_name}"))
    plans = UsdGeom.Xform.Define(stage, f"/{root_name}/Plans")
    set_kind(plans.GetPrim(), "group")
    for r in results:
        name = f"{r.planner}_{r.collision}"
        group = UsdGeom.Xform.Define(stage, f"/{root_name}/Plans/{name}").GetPrim()
        m = r.metrics
        set_attrs(group, "roadtwin:plan", {
            "planner": r.planner, "collision": r.collision, "lengthM": m.length_m, "deviationPct": m.deviation_pct,
            "smoothnessRadPerM": m.smoothness_rad_per_m, "meanClearanceM": _finite(m.mean_clearance_m),
            "minClearanceM": _finite(m.min_clearance_m), "wheelInDefect": m.wheel_in_defect, "seed": int(r.seed),
            "liftM": float(lift_m)})
        z = np.nan_to_num(np.asarray(r.z, dtype=np.float64), nan=0.0)
        curve = UsdGeom.BasisCurves.Define(stage, f"/{root_name}/Plans/{name}/Path")
        _set_curves(curve, [np.column_stack([r.poses[:, :2], z + lift_m])], 0.1, _rgb(r.planner))
        travel = resample_by_length(r.poses, 0.25)
        w = vehicle.wheel_centres(travel)
        tracks = []
        for k in range(4):
            wz = np.nan_to_num(grid.road_height(w[:, k]), nan=0.0)
            tracks.append(np.column_stack([w[:, k], wz + lift_m]))
        _set_curves(UsdGeom.BasisCurves.Define(stage, f"/{root_name}/Plans/{name}/WheelTracks"), tracks, 0.04,
                    tuple(0.5 * c for c in _rgb(r.planner)))
    stage.GetRootLayer().Save()
    return path


def _finite(v: float) -> float:
    return float(v) if math.isfinite(v) else -1.0


def _rgb(planner: str) -> tuple[float, float, float]:
    import matplotlib.colors as mcolors

    return tuple(float(c) for c in mcolors.to_rgb(COLOURS.get(planner, "tab:cyan")))


def _set_curves(curve, polylines: list[np.ndarray], width: float, rgb) -> None:
    pts = np.concatenate(polylines).astype(np.float32)
    curve.CreateTypeAttr(UsdGeom.Tokens.linear)
    curve.CreateCurveVertexCountsAttr(Vt.IntArray([len(p) for p in polylines]))
    curve.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    curve.CreateWidthsAttr(Vt.FloatArray([width]))
    curve.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    curve.CreateDisplayColorAttr(Vt.Vec3fArray([rgb]))
    lo, hi = pts.min(axis=0) - width / 2, pts.max(axis=0) + width / 2
    curve.CreateExtentAttr(Vt.Vec3fArray([tuple(lo.tolist()), tuple(hi.tolist())]))


def write_paths_index(path: Path, root_name: str, layers: list[str]) -> None:
    """``paths.usda``: every planner's path layer sublayered over the town."""
    stage = new_stage(path, root_name, "roadtwin: every planner's path over the town")
    stage.GetRootLayer().subLayerPaths = layers
    stage.OverridePrim(Sdf.Path(f"/{root_name}"))
    stage.GetRootLayer().Save()

