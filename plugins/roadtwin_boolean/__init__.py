"""Boolean merger: defects merged into road segments by manifold3d CSG, as a built-in plugin.

See :mod:`roadtwin_boolean.merger` for the construction (road slab, footprint prisms, defect
columns) and how the top surface and its owners are read back from manifold's face tracking.
"""
from roadtwin_core import hookimpl

from .merger import BooleanBuild, BooleanMerger, BooleanParams


@hookimpl
def roadtwin_register_mergers(register):
    register(BooleanMerger())


__all__ = ["BooleanMerger", "BooleanParams", "BooleanBuild"]
