"""``roadtwin render``: synthetic perception datasets from a composed town.

One concern per module: ``options`` (the command's options as :class:`RenderOptions`, their checks
and the camera rig), ``cameras`` (where the frames' cameras come from), ``lanes`` (the lane a
camera drives in), ``events`` (the ``--events`` drive), ``pipeline`` (frame jobs and what one
worker does with its chunk), ``writers`` (the dataset writer and its format registry), ``run``
(``run_render`` ties them together), ``report`` (what the command prints). Cameras, frames, render
meshes and the renderer contract's data are the framework's (``roadtwin_core.render``).
"""
from .options import MAX_FRAMES, RenderOptions, check_range, parse_size, parse_views
from .run import defect_statistics, run_render
from .writers import FORMATS, WRITERS, DatasetWriter, parse_formats

__all__ = ["DatasetWriter", "FORMATS", "MAX_FRAMES", "RenderOptions", "WRITERS", "check_range", "defect_statistics",
           "parse_formats", "parse_size", "parse_views", "run_render"]
