"""Which material each road kind, defect type and marking colour gets, and what a material is."""
from __future__ import annotations

from dataclasses import dataclass

ST_TILE_M = 4.0  # metres of road per st unit (one texture repeat), for every material


@dataclass(frozen=True)
class MaterialSpec:
    """One ``UsdPreviewSurface`` material: texture files are names under ``textures/``.

    ``diffuse``: sRGB PNG; ``roughness``: linear 8-bit PNG (or a constant when ``None``,
    ``roughness_value``); ``normal``: tangent-space normal map PNG (linear, +z out of the surface;
    ``None`` for flat). ``wrap``: ``repeat`` for surfaces that tile, ``clamp`` for a decal (a
    defect's own texture over its footprint). ``opacity_from_alpha``: the diffuse's alpha drives
    opacity (a stand-alone defect asset fading into whatever road it is shown over; never in a
    composed town, where the defect is cut into the road and nothing lies beneath).
    """

    name: str
    diffuse: str
    roughness: str | None = None
    roughness_value: float = 0.8
    normal: str | None = None
    metallic: float = 0.0
    doc: str = ""
    wrap: str = "repeat"
    opacity_from_alpha: bool = False


# Road kinds -> material; unknown kinds use "asphalt".
KIND_MATERIAL = {"driving": "asphalt_worn", "junction": "asphalt", "shoulder": "shoulder", "sidewalk": "pavers",
                 "parking": "asphalt", "median": "cement", "verge": "grass"}
# The root's ``roadMaterial`` variant set switches the material of driving and junction surfaces.
ROAD_MATERIAL_VARIANTS = {"asphalt": "asphalt_worn", "cobblestone": "cobblestone", "cement": "cement"}
# The unpaved strip beyond the shoulder: a ``vergeMaterial`` variant set (or a renderer's domain
# randomisation) may switch the material of verge surfaces among these.
VERGE_MATERIAL_VARIANTS = {"grass": "grass", "gravel": "gravel", "soil": "soil"}
# Finishes a defect type may name as its ``material`` (contracts.DefectType; the type says which,
# core names no type); a type that names none wears the worn asphalt of the road around it.
DEFECT_FINISHES = ("pothole", "crack", "worn", "asphalt", "cast_iron", "patch",
                   # look-alikes' finishes (plugins/roadtwin_lookalikes)
                   "oil_stain", "tar", "tyre_mark", "wet_patch", "puddle", "debris", "paint_worn", "paint_ghost")
DEFAULT_DEFECT_MATERIAL = "worn"
MARKING_MATERIAL = {"white": "paint_white", "yellow": "paint_yellow"}
# Written and authored like the others but bound by no default rule: a user (or a variant) binds them.
OPTIONAL_MATERIALS = ("pothole_wet",)


def all_materials() -> list[str]:
    """Every material name the catalog uses (what a looks layer authors)."""
    return sorted({*KIND_MATERIAL.values(), *ROAD_MATERIAL_VARIANTS.values(),
                   *VERGE_MATERIAL_VARIANTS.values(), *DEFECT_FINISHES,
                   *MARKING_MATERIAL.values(), "asphalt", "worn", "paint_white", *OPTIONAL_MATERIALS})


def kind_material(kind: str) -> str:
    return KIND_MATERIAL.get(kind, "asphalt")


def marking_material(color: str) -> str:
    return MARKING_MATERIAL.get(color, "paint_white")
