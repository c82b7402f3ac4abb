"""Road materials made elsewhere (``roadtwin reconstruct photo-surfaces``), offered by
``compose --road-textures DIR`` as ``roadMaterial`` variants beside the procedural ones.

The folder holds ``materials.json``: ``{"st_tile_m": 4.0, "materials": [{"name", "diffuse",
"roughness", "normal", "doc", "source", ...}]}`` with the three PNGs named there beside it. A
material must repeat every ``st_tile_m`` metres (the st convention of this package, equal to
``ST_TILE_M``), its name must be a USD identifier and differ from every built-in material and
variant. Bad input is one :class:`~roadtwin_core.RoadtwinError` naming the file.
"""
from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from ..errors import RoadtwinError
from .catalog import ROAD_MATERIAL_VARIANTS, ST_TILE_M, MaterialSpec, all_materials

MATERIALS_FILE = "materials.json"
DEFAULT_ROAD_VARIANT = "asphalt"   # the roadMaterial variant a town selects unless told


def read_road_textures(folder: str | Path) -> list[MaterialSpec]:
    """The materials of ``folder`` (module docstring), their files checked."""
    folder = Path(folder)
    meta_path = folder / MATERIALS_FILE
    if not folder.is_dir():
        raise RoadtwinError(f"{folder}: --road-textures folder not found")
    try:
        meta = json.loads(meta_path.read_text())
    except FileNotFoundError:
        raise RoadtwinError(f"{meta_path}: no {MATERIALS_FILE} (roadtwin reconstruct photo-surfaces writes it)") from None
    except (OSError, ValueError) as exc:
        raise RoadtwinError(f"{meta_path}: cannot read it ({exc})") from None
    tile = meta.get("st_tile_m") if isinstance(meta, dict) else None
    if tile != ST_TILE_M:
        raise RoadtwinError(f"{meta_path}: st_tile_m is {tile!r}; the town's textures repeat every {ST_TILE_M:g} m")
    items = meta.get("materials")
    if not isinstance(items, list) or not items:
        raise RoadtwinError(f"{meta_path}: no materials listed")
    taken = set(all_materials()) | set(ROAD_MATERIAL_VARIANTS)
    specs: list[MaterialSpec] = []
    for item in items:
        name = item.get("name") if isinstance(item, dict) else None
        if not isinstance(name, str) or not name.isidentifier() or not name.isascii():
            raise RoadtwinError(f"{meta_path}: material name {name!r} is not an identifier")
        if name in taken:
            raise RoadtwinError(f"{meta_path}: material {name!r} clashes with a built-in material or another entry")
        taken.add(name)
        files = {}
        for role in ("diffuse", "roughness", "normal"):
            file = item.get(role)
            if file is None and role != "diffuse":
                continue
            if not isinstance(file, str) or Path(file).name != file or not (folder / file).is_file():
                raise RoadtwinError(f"{meta_path}: {name}: {role} file {file!r} not found beside it")
            files[role] = file
        doc = str(item.get("doc", ""))
        if item.get("source"):
            doc = f"{doc} (roadtwin:source: {item['source']})".strip()
        specs.append(MaterialSpec(name, files["diffuse"], files.get("roughness"), normal=files.get("normal"), doc=doc))
    return specs


def copy_road_textures(folder: str | Path, specs: list[MaterialSpec], textures: str | Path) -> dict[str, MaterialSpec]:
    """Copy the materials' files into a town's ``textures/``; the specs by name."""
    for spec in specs:
        for file in filter(None, (spec.diffuse, spec.roughness, spec.normal)):
            shutil.copyfile(Path(folder) / file, Path(textures) / file)
    return {spec.name: spec for spec in specs}


@dataclass(frozen=True)
class RoadLooks:
    """What ``compose --road-textures DIR --road-material NAME`` asks of the town's looks: the
    extra ``roadMaterial`` variants (one per material of DIR, named like it) and the variant
    selected (default: the procedural ``asphalt``)."""

    folder: Path | None = None
    specs: tuple[MaterialSpec, ...] = ()
    selected: str = DEFAULT_ROAD_VARIANT

    def copy_into(self, textures: str | Path) -> dict[str, MaterialSpec]:
        return copy_road_textures(self.folder, list(self.specs), textures) if self.folder else {}

    def town_fields(self) -> dict:
        """``TownParts`` keywords: the extra variants and the selection."""
        return {"road_textures": {s.name: s.name for s in self.specs}, "road_material": self.selected}


def resolve_road_looks(folder: str | Path | None, selected: str | None) -> RoadLooks:
    """``--road-textures`` read and ``--road-material`` checked against every variant there will be."""
    specs = tuple(read_road_textures(folder)) if folder is not None else ()
    variants = [*ROAD_MATERIAL_VARIANTS, *(s.name for s in specs)]
    if selected is not None and selected not in variants:
        raise RoadtwinError(f"--road-material: no roadMaterial variant {selected!r} (variants: {', '.join(variants)})")
    return RoadLooks(Path(folder) if folder is not None else None, specs, selected or DEFAULT_ROAD_VARIANT)
