"""Defect-aware path planning (the paper's decision-making study): footprint, collision, metrics.

Everything here works on a :class:`GridMap` (made from a town by :func:`rasterize` or
:func:`rasterize_scene`); planners are plugins (``roadtwin_register_planners``) found by name, and
use only the names in ``__all__``. The vehicle is :class:`roadtwin_core.vehicle.VehicleParams`
(the one vehicle description); planning sees it through ``VehicleParams.footprint()``. What
``roadtwin plan`` does with all this (outputs, plots, USD curves, bypass-or-cross decisions) lives
in :mod:`roadtwin_core.apps.plan`.

Conventions
-----------
A *pose* is ``(x, y, yaw)``: the rear-axle centre in world metres and the heading in radians
from +x, counter-clockwise. A *path* is an (N, 3) array of poses from the start pose to the goal
pose. Between consecutive poses the vehicle moves linearly in x, y and (shortest way round) in
yaw; two poses at the same point are a turn on the spot, which grid planners (A*, RRT*) use at
their corners. :meth:`CollisionChecker.densify` samples that motion so that no footprint point
moves more than half a cell between samples, and both the planners and the metrics check
exactly those samples, so a path a planner accepted is also a path the metrics accept.

Collision (Zhang et al.: "collision is checked per wheel, not for the body")
---------------------------------------------------------------------------
``wheel``: the four tire contact patches (tire width x contact length) must lie on drivable
cells and on no defect cell; a defect may pass between the wheels (the vehicle straddles it).
``body``: the whole vehicle (body rectangle, overhangs included, never narrower than the outer
tire edges) must lie on drivable cells and cover no defect cell. Footprints are sampled with
points (tires and outline every half cell, the inside every 1/1.5 cell, so every cell lying fully
inside the body holds a point); a cell is hit when a sample point falls in it. The body's points
include the tires' and both levels sample motions at the same poses, so a body-level collision-free
path is always wheel-level collision-free too.

Metrics (the paper's three plus two)
------------------------------------
``length_m``; ``deviation_pct`` = 100 (length / reference - 1) with the reference the shortest
drivable path from start to goal ignoring defects (the straight line when it stays on the
lanes, otherwise a string-pulled 8-connected geodesic); ``smoothness_rad_per_m`` = total absolute
heading change of the path's segments / length; ``mean_clearance_m`` and ``min_clearance_m`` =
distance from each wheel's contact centre to the nearest defect cell centre, averaged over the
four wheels at samples every half cell of travel (the minimum also over turns on the spot);
``wheel_in_defect`` = whether any tire sample point lies on a defect cell anywhere on the path.
"""
from __future__ import annotations

from .collision import COLLISION_MODES, CollisionChecker, check_endpoint
from .footprint import WHEEL_NAMES, Footprint, transform, wrap_angle
from .grid import GridMap, rasterize, rasterize_scene
from .metrics import PathMetrics, heading_changes, path_metrics, resample_by_length
from .reference import (drivable_distance, lane_headings, polyline_length, reference_frame, reference_path,
                        segment_drivable)
from .run import PlanFailure, PlannerOutput, PlanResult, parse_pose, plan_path

__all__ = [
    "COLLISION_MODES", "CollisionChecker", "check_endpoint", "WHEEL_NAMES", "Footprint", "transform", "wrap_angle",
    "GridMap", "rasterize", "rasterize_scene",
    "PathMetrics", "heading_changes", "path_metrics", "resample_by_length", "drivable_distance", "lane_headings",
    "polyline_length", "reference_frame", "reference_path", "segment_drivable", "PlanFailure", "PlannerOutput",
    "PlanResult", "parse_pose", "plan_path",
]
