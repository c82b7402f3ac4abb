"""``roadtwin reconstruct``: real sensor data -> road surface and defect models, through the
reconstructor plugins (``lidar_surface``, ``stereo_defects``; the core never imports a plugin).

``inputs`` builds and checks what the Reconstructor contract (:class:`roadtwin_core.contracts.Reconstructor`)
hands a plugin's ``run``, typed: :class:`SurfaceInputs`, :class:`DefectInputs` and, for labelled
photos (``photo_defects``), :class:`PhotoInputs` resolved into a :class:`PhotoSet`; ``run`` checks
the output, configures the plugin's ``Params``, runs it and writes. A Python caller does what the
command does::

    from roadtwin_core.apps.reconstruct import SurfaceInputs, reconstruct_surface
    reconstruct_surface(SurfaceInputs(frames=[Path("scan.ply")]), Path("surface.usda"))
"""
from .inputs import (ROAD_LABELS, DefectInputs, PhotoInputs, PhotoSet, SurfaceInputs, check_defect_inputs,
                     check_photo_inputs, check_surface_inputs)
from .run import (DefectReconstruction, PhotoReconstruction, SurfaceReconstruction, reconstruct_defects,
                  reconstruct_photo_surfaces, reconstruct_photos, reconstruct_surface)

__all__ = ["DefectInputs", "DefectReconstruction", "PhotoInputs", "PhotoReconstruction", "PhotoSet", "ROAD_LABELS",
           "SurfaceInputs", "SurfaceReconstruction", "check_defect_inputs", "check_photo_inputs",
           "check_surface_inputs", "reconstruct_defects", "reconstruct_photo_surfaces", "reconstruct_photos",
           "reconstruct_surface"]
