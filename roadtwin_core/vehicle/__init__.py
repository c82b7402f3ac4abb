"""Vehicles on roads: parameters, the physics backends' contract, ride metrics and test roads
(the vibration sweep that drives them is an app: ``roadtwin_core.apps.sweep``). Backends are plugins
(``roadtwin_register_physics_backends``); this package never imports one.
"""
from .metrics import (ALPHA, comfort_band, comfort_bands_containing, vibration_degree, window_metrics, wk_digital,
                      wk_magnitude, wk_weight)
from .roads import (REFERENCE_DEFECTS, Crossing, RoadMesh, Scenario, ReferenceDefect, fill_defects, grid_mesh,
                    load_town_scenario, offset_polyline, resample_path,
                    resampled_path_at, step_road, straight_road, straight_road_scenario, town_scenario)
from .vehicle import (DEFAULT_CAR, FOOTPRINT_FIELDS, GRAVITY, PAPER_CAR_FILE, QuarterCarParams, SimParams, Traces,
                      VehicleParams, VehicleRun, check_runs, load_full_vehicle, load_vehicle, paper_car, plain_vehicles,
                      vehicle_from_dict, vehicle_to_toml)

__all__ = [
    "ALPHA", "comfort_band", "comfort_bands_containing", "vibration_degree", "window_metrics", "wk_digital",
    "wk_magnitude", "wk_weight", "REFERENCE_DEFECTS", "Crossing", "RoadMesh", "Scenario", "ReferenceDefect",
    "fill_defects", "grid_mesh", "load_town_scenario", "offset_polyline", "resample_path", "resampled_path_at",
    "step_road", "straight_road", "straight_road_scenario", "town_scenario", "DEFAULT_CAR", "GRAVITY",
    "QuarterCarParams", "SimParams", "Traces", "VehicleParams", "VehicleRun", "check_runs", "load_vehicle",
    "plain_vehicles", "vehicle_from_dict", "vehicle_to_toml",
    "FOOTPRINT_FIELDS", "PAPER_CAR_FILE", "load_full_vehicle", "paper_car",
]
