"""Built-in parametric defect types: pothole, depression, bump, rut, manhole, crack, patch, ravelling,
alligator.

Why a plugin: the built-ins register exactly as a third-party defect type would (entry point
``defects = "roadtwin_defects"`` in group ``roadtwin``), using only roadtwin_core's public API.
Each type is one small module; ``_mesh`` holds the shared footprint + height -> mesh recipe.
"""
from roadtwin_core import hookimpl

from .alligator import Alligator
from .bump import Bump
from .crack import Crack
from .depression import Depression
from .manhole import Manhole
from .patch import Patch
from .pothole import Pothole
from .ravelling import Ravelling
from .rut import Rut

__all__ = ["Alligator", "Bump", "Crack", "Depression", "Manhole", "Patch", "Pothole", "Ravelling", "Rut"]


@hookimpl
def roadtwin_register_defect_types(register):
    for thing in (Pothole(), Depression(), Bump(), Rut(), Manhole(), Crack(), Patch(), Ravelling(), Alligator()):
        register(thing)
