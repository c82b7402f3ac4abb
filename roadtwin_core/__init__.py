"""roadtwin: road digital twins with defects, as OpenUSD.

The public API, what plugins and users may import, is this module's ``__all__`` plus the
``__all__`` of these public modules:

- ``roadtwin_core.geometry``: mesh outlines, edges, vertical ray hits.
- ``roadtwin_core.remesh``: the even road re-meshing every merger shares.
- ``roadtwin_core.atomic``: write a whole output (folder or file) or nothing.
- ``roadtwin_core.planning``: vehicle footprint, collision checker, reference paths and frames,
  path metrics (what planners need).
- ``roadtwin_core.vehicle``: the vehicle description, runs, traces, ride metrics.
- ``roadtwin_core.render``: render scenes, cameras, frames and their parameters.
- ``roadtwin_core.usd``: layouts, library assets and town stages in and out.

What each kind of plugin object must provide is in :mod:`roadtwin_core.contracts` (its protocols
are re-exported here). Every other module is private to the framework and may change without
notice; ``tests/core/test_public_api.py`` checks that the plugins keep to this.
"""
import importlib

# Names load on first use (PEP 562), so importing one public module (e.g. the physics kernels'
# ``roadtwin_core.vehicle`` on a GPU machine with only numpy + warp) does not pull in shapely,
# scipy and pluggy through the data model, surfaces and plugin manager.
_WHERE = {
    **dict.fromkeys(("DatasetFormat", "DefectType", "Exporter", "LayoutImporter", "Merger", "PhysicsBackend",
                     "Planner", "Reconstructor", "Renderer", "RendererBase", "Sensor", "SurfaceSource"), "contracts"),
    "RoadtwinError": "errors",
    **dict.fromkeys(("MARKING_TYPES", "ComposeRules", "DefectLook", "DefectModel", "FixedDefect", "LaneMarking",
                     "MapObject", "MergedSegment", "Placement", "RoadSegment", "TownLayout", "polygon_area",
                     "triangle_areas"), "model"),
    **dict.fromkeys(("apply_params", "check_params", "describe_params", "field", "make_params"), "params"),
    **dict.fromkeys(("PluginManager", "get_plugin_manager", "hookimpl", "reset_plugin_manager"), "plugins"),
    **dict.fromkeys(("FlatSurface", "GridSurface", "SampledSurface", "SumSurface", "SurfaceModel",
                     "iso8608_surface", "parse_surface"), "surface"),
}


def __getattr__(name: str):
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module 'roadtwin_core' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{where}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_WHERE))


__version__ = "0.1.0"

__all__ = [*_WHERE, "__version__"]
