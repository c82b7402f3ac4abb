"""OpenDRIVE layout importer: ``roadtwin import opendrive MAP.xodr -o LAYOUT.usda``.

A small parser of its own (xml.etree) with closed-form reference-line evaluation; see
:mod:`roadtwin_opendrive.importer` for what a map becomes and why. Public:
:class:`OpenDriveImporter` (the registered layout importer), :class:`OpenDriveParams`,
:func:`load_network` (layout, with the road marks as lane markings, plus road/junction counts and
the junctions' connecting-lane centre lines), :func:`read_xodr` and :class:`ReferenceLine` (for tests and tools).
"""
from roadtwin_core import hookimpl

from ._refline import ReferenceLine, clothoid, eval_cubics, geometry_xyh
from ._xodr import read_xodr
from .importer import OpenDriveImporter, OpenDriveNetwork, OpenDriveParams, load_network


@hookimpl
def roadtwin_register_layout_importers(register):
    register(OpenDriveImporter())


__all__ = ["OpenDriveImporter", "OpenDriveParams", "OpenDriveNetwork", "load_network", "read_xodr",
           "ReferenceLine", "clothoid", "eval_cubics", "geometry_xyh"]
