"""OpenCRG plugin: ASAM OpenCRG ``.crg`` road surfaces in and out.

- :func:`read_crg` / :func:`write_crg`: the text (LRFI, LDFI) and binary (KRBI, KDBI) formats,
  as a :class:`CRG` (u/v grid, heights, reference line, options); see ``crg.py``.
- :class:`CrgSurface`: a CRG as a :class:`roadtwin_core.SurfaceModel` (world xy -> u, v along the
  reference line -> bilinear height, missing cells filled per OpenCRG's GRID_NAN_MODE).
- Exporter ``crg`` (suffix ``.crg``): a composed town's road surface sampled along its longest
  driving lane into a 5 cm grid, written as KRBI; see ``export.py``.
"""
import numpy as np

from roadtwin_core import RoadtwinError, hookimpl

from .crg import CRG, CrgSurface, fill_missing, read_crg, write_crg
from .export import CrgExporter, drape, lane_chain, lane_crg

__all__ = ["CRG", "CrgSurface", "CrgExporter", "drape", "fill_missing", "lane_chain", "lane_crg", "read_crg",
           "write_crg"]


@hookimpl
def roadtwin_register_exporters(register):
    register(CrgExporter())


class CrgSurfaceSource:
    """``--surface crg:PATH``: an OpenCRG road as the town's elevation source."""

    name = "crg"
    description = "an OpenCRG road (.crg) as the town's elevation: --surface crg:ROAD.crg"

    def load(self, arg, bounds, seed):
        surface = CrgSurface.from_file(arg)
        kept = int(np.isnan(surface.grid).sum())
        if kept:  # GRID_NAN_MODE = 0: OpenCRG evaluates NaN there; a town's elevation cannot
            raise RoadtwinError(f"{arg}: GRID_NAN_MODE 0 keeps {kept} missing cell(s); an elevation source needs "
                                "heights everywhere (GRID_NAN_MODE 1 or 2 in $ROAD_CRG_MODS)")
        return surface


@hookimpl
def roadtwin_register_surface_sources(register):
    register(CrgSurfaceSource())
