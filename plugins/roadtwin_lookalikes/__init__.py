"""Look-alikes: surface features that are not defects (oil and tar stains, tar-sealed cracks,
tyre marks, wet patches and puddles, debris, patch seams, worn and ghost paint).

Why defect types and not a new plugin kind: a look-alike needs everything a defect gets (a
seeded model library, placement by the layout's weights and spacing, merging into the road so
no z-fighting film floats above it, a material bound per type, collision) and nothing else; a
new hook would duplicate that path. What differs is what it *means*: each type says
``semantic_class = "road_lookalike"`` and the stage labels it ``["road", "road_lookalike",
<type>]``; class maps (``builtin:road_defects_br``) map the type names to the road classes.
Registered through the ``roadtwin`` entry-point group like the built-in defects.
"""
from roadtwin_core import hookimpl

from .types import (ALL, SEMANTIC_CLASS, Debris, GhostPaint, OilStain, PatchSeam, Puddle, SealedCrack, TarStain,
                    TyreMark, WetPatch, WornPaint)

__all__ = ["ALL", "SEMANTIC_CLASS", "Debris", "GhostPaint", "OilStain", "PatchSeam", "Puddle", "SealedCrack",
           "TarStain", "TyreMark", "WetPatch", "WornPaint"]


@hookimpl
def roadtwin_register_defect_types(register):
    for cls in ALL:
        register(cls())
