"""``roadtwin reconstruct``: real sensor data -> road surface and defect models, through the
reconstructor plugins (``lidar_surface``, ``stereo_defects``; the core never imports a plugin).

``inputs`` builds and checks what the Reconstructor contract (:class:`roadtwin_core.contracts.Reconstructor`)
hands a plugin's ``run``, typed: :class:`SurfaceInputs` and :class:`DefectInputs`; ``run`` checks
the output, configures the plugin's ``Params``, runs it and writes. A Python caller does what the
command does::

    from roadtwin_core.apps.reconstruct import SurfaceInputs, reconstruct_surface
    reconstruct_surface(SurfaceInputs(frames=[Path("scan.ply")]), Path("surface.usda"))
"""
from .inputs import ROAD_LABELS, DefectInputs, SurfaceInputs, check_defect_inputs, check_surface_inputs
from .run import DefectReconstruction, SurfaceReconstruction, reconstruct_defects, reconstruct_surface

__all__ = ["DefectInputs", "DefectReconstruction", "ROAD_LABELS", "SurfaceInputs", "SurfaceReconstruction",
           "check_defect_inputs", "check_surface_inputs", "reconstruct_defects", "reconstruct_surface"]
