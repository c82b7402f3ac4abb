"""Looks: appearance as data. Seeded procedural textures written as PNG next to a stage, and the
catalog of ``UsdPreviewSurface`` materials that bind them to roads, defects and markings.

Texture coordinates: every rendered mesh carries ``primvars:st`` (texCoord2f, vertex
interpolation). One st unit covers ``ST_TILE_M`` metres of road, for every material, so a
texture's content is drawn at its real scale inside a ``ST_TILE_M`` square tile that repeats
(no ``UsdTransform2d`` needed, which not every importer honours). Driving-lane segments with a
centreline get lane-aligned st (u along travel, v across, v = 0.5 on the centreline) so the
tire-polished wheel paths of the asphalt textures lie under the wheels; everything else is
world-planar (st = xy / ST_TILE_M).
"""
import importlib

from .catalog import (DEFAULT_DEFECT_MATERIAL, DEFECT_FINISHES, KIND_MATERIAL, MARKING_MATERIAL, OPTIONAL_MATERIALS,
                      ROAD_MATERIAL_VARIANTS, ST_TILE_M, VERGE_MATERIAL_VARIANTS, MaterialSpec, all_materials,
                      kind_material, marking_material)

_LAZY = {"write_textures": ".textures", "write_textures_cached": ".cache"}


def __getattr__(name: str):
    """The texture generators import scipy.fft and more (~0.2 s): only for whoever makes textures."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DEFAULT_DEFECT_MATERIAL", "DEFECT_FINISHES", "KIND_MATERIAL", "MARKING_MATERIAL", "OPTIONAL_MATERIALS",
           "ROAD_MATERIAL_VARIANTS", "ST_TILE_M", "VERGE_MATERIAL_VARIANTS", "MaterialSpec", "all_materials",
           "kind_material", "marking_material", "write_textures", "write_textures_cached"]
