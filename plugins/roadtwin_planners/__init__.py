"""Built-in path planners: astar, rrtstar, lattice, hybrid_astar (Zhang et al.'s comparison).

Each planner is one module with a small class: ``name``, ``description``, a ``Params``
dataclass (bounds checked by roadtwin_core) and
``plan(grid, start, goal, vehicle, collision, params, rng) -> PlannerOutput``, where
``grid`` is a :class:`roadtwin_core.planning.GridMap`, ``vehicle`` a
:class:`roadtwin_core.planning.Footprint` (``VehicleParams.footprint()``) and ``collision``
"wheel" or "body". :class:`roadtwin_core.planning.PlannerOutput` carries the poses ((N, 3), or
None when no path was found) and the call's statistics (expansions, tree size): planners keep no
per-call state on themselves, since one instance serves every call and executors copy it. The returned path
starts at the start pose and ends at the goal pose; every motion in it has been accepted by
:class:`roadtwin_core.planning.CollisionChecker`, which the core's metrics use too. All planners
are deterministic for a given rng seed.

Registered through the entry point ``planners = "roadtwin_planners"`` exactly as a third-party
planner would be; this package uses only roadtwin_core's modules.
"""
from roadtwin_core import hookimpl

from .astar import AStar
from .hybrid_astar import HybridAStar
from .lattice import StateLattice
from .rrtstar import RRTStar

__all__ = ["AStar", "HybridAStar", "RRTStar", "StateLattice"]


@hookimpl
def roadtwin_register_planners(register):
    for thing in (AStar(), RRTStar(), StateLattice(), HybridAStar()):
        register(thing)
