"""Built-in renderer ``warp``: synthetic perception data from composed towns.

Ray casting on warp (CPU and CUDA) over one labelled triangle mesh of the town: z-depth,
camera-frame normals, semantic classes, defect instances, rectified-stereo disparity with an
occlusion mask, and shaded RGB from the materials bound in the stage (UsdPreviewSurface diffuse,
roughness and normal textures, MIP-mapped with anisotropic filtering: ``textures.py``), sun and
sky with ray-traced shadows, fog, wet road, dusk. The kernels live in ``raycast.py`` and use only
numpy and warp, so they are benchmarked without USD (``bench/render.py``). On CUDA,
``render_finished`` also runs the camera model and the ego-lane labels as kernels on batches of
frames (``post.py``, ``post_kernels.py``). ``roadtwin render`` (``roadtwin_core.cli.render``)
drives it and writes the datasets.
"""
from roadtwin_core import hookimpl

from .renderer import PreparedScene, WarpRenderer

__all__ = ["WarpRenderer", "PreparedScene"]


@hookimpl
def roadtwin_register_renderers(register):
    register(WarpRenderer())
