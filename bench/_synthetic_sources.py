"""Provenance of a synthetic set: the real photo frames whose pixels entered it (issue 21's CV leak).

A set made with the photo defect library (``roadtwin reconstruct photos``) or photo road
surfaces (``roadtwin reconstruct photo-surfaces``) carries pixels of real train frames as
textures. The mixed arm's cross-validation (bench/_perception_cv.py) scores a synthetic set on
held-out train roads; if the set holds their defects, the score is not held out. So
bench/synthetic_set.py records, per scene, what it composed, and writes for the packed set

    OUT/synthetic/sources.json  {"frames": [stems, sorted], "scenes": {scene: {"defect_assets":
                                 {asset: stem}, "road_materials": {material: [stems]}}}}

- defect assets: those the composed town PLACES (``layers/defects.usda``: each instance's
  ``roadtwin:source`` names ``library/<asset>.usda``), each read back for its own
  ``roadtwin:source`` (``photo /path/<stem>.jpg (pothole instance 3); license: ...``, the photo
  plugin's format; ``roadtwin:params`` ``frame`` where the string does not parse). Procedural
  assets name no photo and add nothing.
- road materials: those a scene wears (compose ``--road-material``, render ``--material``) from
  the ``--road-textures`` folder's ``materials.json`` (each material's ``frame`` and the
  ``frame`` of each of its quilted ``sources``).

Stems are file names without extension: they match bench/perception.py's real frame stems.
Deterministic (sorted, sort_keys) and written atomically. docs/architecture.md: the framework
writes provenance as ``roadtwin:source``; this module only reads it.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

from pxr import Sdf

from roadtwin_core.apps.library import read_interface
from roadtwin_core.atomic import atomic_write_bytes
from roadtwin_core.errors import RoadtwinError

from _perception_data import frame_stem

_PHOTO_SOURCE = re.compile(r"^photo (?P<path>.+?) \([^()]* instance \d+\); license:")


def asset_frame(asset: Path) -> str | None:
    """The stem of the photo frame a library asset was cut from, or None (not from a photo)."""
    attrs = read_interface(asset).attrs                  # the root prim's attributes, geometry not loaded
    source = str(attrs.get("roadtwin:source") or "")
    match = _PHOTO_SOURCE.match(source)
    if match:
        return frame_stem(match["path"])
    if source.startswith("photo ") and "roadtwin:params" in attrs:
        try:
            frame = json.loads(attrs["roadtwin:params"] or "{}").get("frame")
        except ValueError:
            frame = None
        if frame:
            return frame_stem(frame)
        raise RoadtwinError(f"{asset}: roadtwin:source {source!r} names a photo but not its frame")
    return None


def placed_assets(town: Path) -> dict[str, str | None]:
    """Library asset name -> its photo frame stem (or None), for every asset the town places."""
    layer_path = town / "layers" / "defects.usda"
    if not layer_path.is_file():
        return {}
    layer = Sdf.Layer.FindOrOpen(str(layer_path))
    assets: dict[str, str | None] = {}
    for root in layer.rootPrims:
        group = layer.GetPrimAtPath(root.path.AppendChild("Defects"))
        for inst in group.nameChildren if group else []:
            attr = inst.attributes.get("roadtwin:source")
            if attr is None or not attr.default:
                continue
            asset = (layer_path.parent / attr.default.path).resolve()
            if asset.stem not in assets:
                assets[asset.stem] = asset_frame(asset)
    return assets


def material_frames(road_textures: Path | None, worn: list[str]) -> dict[str, list[str]]:
    """Photo road material name -> the stems of its source frames, for the worn ones of the folder."""
    if road_textures is None or not worn:
        return {}
    meta_path = Path(road_textures) / "materials.json"
    try:
        materials = {m["name"]: m for m in json.loads(meta_path.read_text())["materials"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RoadtwinError(f"{meta_path}: cannot read its materials ({exc.__class__.__name__})") from None
    out = {}
    for name in sorted(set(worn) & set(materials)):
        m = materials[name]
        frames = [m.get("frame")] + [s.get("frame") for s in m.get("sources", []) if isinstance(s, dict)]
        if not any(frames):
            raise RoadtwinError(f"{meta_path}: material {name!r} records no source frame")
        out[name] = sorted({frame_stem(f) for f in frames if f})
    return out


def scene_sources(town: Path, road_textures: Path | None, worn: list[str]) -> dict:
    """One scene's provenance: the photo defect assets it places, the photo road materials it wears."""
    return {"defect_assets": {k: v for k, v in sorted(placed_assets(town).items()) if v},
            "road_materials": material_frames(road_textures, worn)}


def write_json(path: Path, obj: dict) -> Path:
    return atomic_write_bytes(path, (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode())


def set_sources(scenes: dict[str, dict]) -> dict:
    """The packed set's record from its scenes' records: every frame stem, sorted."""
    frames = set()
    for rec in scenes.values():
        frames |= set(rec["defect_assets"].values())
        for stems in rec["road_materials"].values():
            frames |= set(stems)
    return {"frames": sorted(frames), "scenes": dict(sorted(scenes.items())),
            "about": "stems of the real photo frames whose pixels entered this set (bench/_synthetic_sources.py); "
                     "the mixed arm's CV refuses folds whose held-out frames are listed here"}
