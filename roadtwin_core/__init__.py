"""roadtwin: road digital twins with defects, as OpenUSD.

The public API is what this module exports; everything else is private to the framework.
"""
from .errors import RoadtwinError
from .model import (MARKING_TYPES, ComposeRules, DefectModel, FixedDefect, LaneMarking, MergedSegment, Placement,
                    RoadSegment, TownLayout, polygon_area, triangle_areas)
from .params import check_params, describe_params, field, make_params
from .plugins import PluginManager, get_plugin_manager, hookimpl, reset_plugin_manager
from .surface import (FlatSurface, GridSurface, SampledSurface, SumSurface, SurfaceModel,
                      iso8608_surface, parse_surface)

__version__ = "0.1.0"

__all__ = [
    "RoadtwinError", "MARKING_TYPES", "LaneMarking", "ComposeRules", "DefectModel", "FixedDefect", "MergedSegment", "Placement", "RoadSegment",
    "TownLayout", "polygon_area", "triangle_areas", "check_params", "describe_params", "field",
    "make_params", "PluginManager", "get_plugin_manager", "hookimpl", "reset_plugin_manager",
    "FlatSurface", "GridSurface", "SampledSurface", "SumSurface", "SurfaceModel",
    "iso8608_surface", "parse_surface", "__version__",
]
