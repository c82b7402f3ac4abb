"""Reading a library folder: its asset files, their interfaces (no geometry loaded), one asset by name."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pxr import Usd, UsdGeom

from ...errors import RoadtwinError
from ...model import DefectModel
from ...usd.checks import open_stage
from ...usd.library import library_asset_files, read_defect_asset

__all__ = ["AssetDetails", "AssetInterface", "asset_files", "find_asset", "library_folder", "list_assets",
           "read_interface", "show_asset"]


def library_folder(path: str | Path | None = None) -> Path:
    """The library folder: ``path``, else ``$ROADTWIN_LIBRARY``, else ``./library``."""
    return Path(path) if path is not None else Path(os.environ.get("ROADTWIN_LIBRARY", "library"))


def asset_files(folder: Path) -> list[Path]:
    """Interface files of a library folder (``*.usda`` / ``*.usd`` / ``*.usdc``, payloads excluded)."""
    if not folder.is_dir():
        raise RoadtwinError(f"{folder}: no such library folder")
    return library_asset_files(folder)


@dataclass
class AssetInterface:
    """What an asset's interface file says without its geometry: the root prim's name, its
    ``roadtwin:`` / ``semantics:`` attributes, the payload paths it references and its extent."""

    name: str
    attrs: dict[str, Any]
    payloads: list[str]
    extent: list[tuple[float, ...]] | None


def read_interface(path: Path) -> AssetInterface:
    """Root-prim attributes, labels and payload paths of an asset, geometry not loaded."""
    stage = open_stage(path, "defect asset", load=Usd.Stage.LoadNone)
    root = stage.GetDefaultPrim()
    if not root.HasAttribute("roadtwin:defect:type"):
        raise RoadtwinError(f"{path}: not a defect asset (no roadtwin:defect:type on {root.GetPath()})")
    attrs = {}
    for a in root.GetAttributes():
        if a.GetName().startswith(("roadtwin:", "semantics:")):
            v = a.Get()
            attrs[a.GetName()] = list(v) if hasattr(v, "__len__") and not isinstance(v, str) else v
    payloads = []
    for layer_spec in (root.GetPrimStack() or []):
        for item in layer_spec.payloadList.GetAddedOrExplicitItems():
            if item.assetPath:
                payloads.append(item.assetPath)
    extent = UsdGeom.ModelAPI(root).GetExtentsHint()
    return AssetInterface(root.GetName(), attrs, payloads,
                          [tuple(float(x) for x in e) for e in extent] if extent else None)


def list_assets(folder: Path) -> tuple[list[tuple[Path, AssetInterface]], list[str]]:
    """(each asset file with its interface, one line per file that is not a defect asset)."""
    assets, skipped = [], []
    for p in asset_files(folder):
        try:
            assets.append((p, read_interface(p)))
        except RoadtwinError as exc:
            skipped.append(str(exc))
    return assets, skipped


def find_asset(folder: Path, name: str) -> Path:
    """The asset called ``name``: a file stem or name first, else a root prim's name."""
    files = asset_files(folder)
    for p in files:
        if p.stem == name or p.name == name:
            return p
    for p in files:  # by prim name
        try:
            if read_interface(p).name == name:
                return p
        except RoadtwinError:
            continue
    known = ", ".join(p.stem for p in files[:12]) or "none"
    raise RoadtwinError(f"{folder}: no asset {name!r} (known: {known}{' ...' if len(files) > 12 else ''})")


@dataclass
class AssetDetails:
    path: Path
    interface: AssetInterface
    model: DefectModel        # the geometry, read (and checked) through read_defect_asset


def show_asset(folder: Path, name: str) -> AssetDetails:
    """Everything ``roadtwin library show`` prints about one asset."""
    path = find_asset(folder, name)
    return AssetDetails(path, read_interface(path), read_defect_asset(path))
