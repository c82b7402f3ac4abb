"""Torch ``Dataset`` classes built on first use, so that importing a dataset reader (or
``roadtwin_core.datasets``) does not import torch: the readers work with numpy + Pillow alone."""
from __future__ import annotations

from typing import Callable


def lazy_classes(module: str, makers: dict[str, Callable[[], type]]) -> Callable[[str], type]:
    """A module ``__getattr__`` (PEP 562) that builds each named class by calling its maker once,
    on first access, and returns the same class afterwards."""
    made: dict[str, type] = {}

    def __getattr__(name: str) -> type:
        if name not in makers:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        if name not in made:
            made[name] = makers[name]()
        return made[name]

    return __getattr__
