"""Seeded procedural textures (PLACEHOLDER: flat colours until the texture generator lands)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .catalog import MaterialSpec

_FLAT = {"asphalt": (60, 60, 62), "asphalt_worn": (80, 80, 80), "cobblestone": (110, 100, 90),
         "cement": (170, 168, 160), "pavers": (150, 140, 130), "paint_white": (235, 235, 230),
         "paint_yellow": (230, 180, 40), "pothole": (40, 36, 32), "crack": (15, 15, 15), "worn": (90, 88, 85),
         "cast_iron": (50, 48, 46), "patch": (45, 45, 48)}


def write_textures(folder: str | Path, seed: int = 0, size: int = 256) -> dict[str, MaterialSpec]:
    """Write every built-in material's textures into ``folder``; return the specs by name."""
    from PIL import Image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    specs = {}
    for name, rgb in _FLAT.items():
        img = np.empty((size, size, 3), np.uint8)
        img[:] = rgb
        Image.fromarray(img).save(folder / f"{name}_diffuse.png", optimize=False)
        specs[name] = MaterialSpec(name, f"{name}_diffuse.png")
    return specs
