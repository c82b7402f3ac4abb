"""Running a reconstructor plugin: inputs checked, output checked, ``Params`` configured, run, written.

The plugin is asked for by name through the plugin manager. Its ``Params`` get the fields the
command sets from its own options (``voxel_m``, ``radius_m``, ``align`` for a surface;
``disparity_scale``, ``grid_m`` for defects: the contract's dataclasses declare them), then the
``--param`` values over them. Photos (``photo_defects``) set no field from options: their
settings are all ``--param``. Bad input is one :class:`~roadtwin_core.RoadtwinError` and nothing
is written.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ...atomic import output_path
from ...errors import RoadtwinError
from ...params import apply_params, make_params
from ...plugins import PluginManager, get_plugin_manager
from ...usd.library import DEFECT_CLASS
from .inputs import (DefectInputs, PhotoInputs, PhotoSet, SurfaceInputs, check_defect_inputs, check_photo_inputs,
                     check_surface_inputs)

__all__ = ["DefectReconstruction", "PhotoReconstruction", "SurfaceReconstruction", "reconstruct_defects",
           "reconstruct_photo_surfaces", "reconstruct_photos", "reconstruct_surface"]

SURFACE_SUFFIXES = (".usda", ".usd", ".usdc")


@dataclass
class SurfaceReconstruction:
    surface: Any          # what the plugin's run returned (a SurfaceModel: vertices, faces)
    path: Path            # the asset written


@dataclass
class DefectReconstruction:
    result: Any           # what the plugin's run returned (models, labels)
    paths: list           # the assets written


def reconstruct_surface(inputs: SurfaceInputs, out: str | Path, *, reconstructor: str = "lidar_surface",
                        voxel_m: float = 0.05, radius_m: float = 0.08, align: bool = True,
                        params: dict[str, Any] | None = None, pm: PluginManager | None = None) -> SurfaceReconstruction:
    """LiDAR frames -> a road surface library asset at ``out`` (a Z-up mesh in metres).
    ``params``: values for the reconstructor's ``Params`` (``--param``)."""
    inputs = check_surface_inputs(inputs)
    out = Path(out)
    if out.suffix not in SURFACE_SUFFIXES:
        raise RoadtwinError(f"{out}: the surface asset must be a .usda, .usd or .usdc file")
    output_path(out)
    rec = _reconstructor(pm, reconstructor, "surface", "a surface")
    checked = _params(rec, reconstructor, {"voxel_m": voxel_m, "radius_m": radius_m, "align": align}, params)
    surface = rec.run(inputs.as_dict(), checked)
    return SurfaceReconstruction(surface, rec.write(surface, out))


def reconstruct_defects(inputs: DefectInputs, out: str | Path, *, reconstructor: str = "stereo_defects",
                        disparity_scale: float = 1.0, grid_m: float = 0.01, params: dict[str, Any] | None = None,
                        pm: PluginManager | None = None) -> DefectReconstruction:
    """A disparity map or stereo pair -> a folder ``out`` (replaced atomically) with one defect
    asset per instance, mask.png and instances.json. ``params``: values for the reconstructor's
    ``Params`` (``--param``)."""
    out = Path(out)
    output_path(out, "dir")
    inputs = check_defect_inputs(inputs)
    rec = _reconstructor(pm, reconstructor, "defects", "defects")
    checked = _params(rec, reconstructor, {"disparity_scale": disparity_scale, "grid_m": grid_m}, params)
    result = rec.run(inputs.as_dict(), checked)
    return DefectReconstruction(result, rec.write(result, out))


@dataclass
class PhotoReconstruction:
    result: Any           # what the plugin's run returned (models, skipped instances)
    paths: list           # the assets written
    photos: int           # how many photos were read


def reconstruct_photos(inputs: PhotoInputs, out: str | Path, *, reconstructor: str = "photo_defects",
                       params: dict[str, Any] | None = None, pm: PluginManager | None = None) -> PhotoReconstruction:
    """Labelled road photos + their camera rig -> a folder ``out`` (replaced atomically) of
    textured defect library assets, one per labelled defect instance (``compose --library``
    reads them). The class map's classes filled from a registered defect type (not a look-alike)
    are the ones reconstructed. ``params``: values for the reconstructor's ``Params`` (``--param``)."""
    return _run_photos(inputs, out, reconstructor, params, pm, ("defects", "defects"), lambda photos: {})


def reconstruct_photo_surfaces(inputs: PhotoInputs, out: str | Path, *, reconstructor: str = "photo_surfaces",
                               params: dict[str, Any] | None = None, pm: PluginManager | None = None,
                               progress: Callable[[int, int], None] | None = None) -> PhotoReconstruction:
    """Labelled road photos + their camera rig -> a folder ``out`` (replaced atomically) of
    seamless road materials cut from their defect-free road (``compose --road-textures`` reads
    it). The plugin reads what :class:`PhotoSet` gives, plus ``road_classes`` (the class map's
    road: :func:`~.inputs.road_classes`) and ``progress(done, total)`` over the frames."""
    return _run_photos(inputs, out, reconstructor, params, pm, ("materials", "road materials"),
                       lambda photos: {"road_classes": photos.lane_classes, "progress": progress})


def _run_photos(inputs: PhotoInputs, out: str | Path, reconstructor: str, params: dict[str, Any] | None,
                pm: PluginManager | None, produces: tuple[str, str],
                extra: Callable[[PhotoSet], dict[str, Any]]) -> PhotoReconstruction:
    """What both photo commands do: output checked, photos resolved, the plugin (``produces``:
    its kind and how a message names it) run on the :class:`PhotoSet` plus ``extra(photos)``, written."""
    out = Path(out)
    output_path(out, "dir")
    pm = pm or get_plugin_manager()
    photos = check_photo_inputs(inputs, defect_types(pm))
    rec = _reconstructor(pm, reconstructor, *produces)
    checked = _params(rec, reconstructor, {}, params)
    result = rec.run({**photos.as_dict(), **extra(photos)}, checked)
    return PhotoReconstruction(result, rec.write(result, out), len(photos.images))


def defect_types(pm: PluginManager) -> set[str]:
    """The registered defect types that are defects (a look-alike's ``semantic_class`` says it is not)."""
    return {name for name, t in pm.registry("defect_types").items()
            if getattr(t, "semantic_class", DEFECT_CLASS) == DEFECT_CLASS}


def _reconstructor(pm: PluginManager | None, name: str, produces: str, what: str):
    rec = (pm or get_plugin_manager()).get("reconstructors", name)
    if rec.produces != produces:
        raise RoadtwinError(f"reconstructor {name!r} does not produce {what}")
    return rec


def _params(rec, name: str, from_options: dict[str, Any], values: dict[str, Any] | None):
    """The plugin's ``Params`` with the command's own options set, then ``--param`` over them."""
    params = make_params(rec.Params, from_options, name)
    return apply_params(params, values or {}, f"reconstructor {name}")
