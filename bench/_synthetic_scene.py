"""What bench/synthetic_set.py composes and renders each scene with: the layout copy with its
rules' weights, the scene's share of the photo library, the render's views and class map."""
from __future__ import annotations

import functools
import sys
from pathlib import Path

from pxr import Sdf

from roadtwin_core.apps.library import read_interface

# Look-alikes beside the defects, per unit of the layout's own pothole weight 5 (the highway's):
# the stains, sealed cracks, tyre marks and seams a Brazilian survey frame shows.
LOOKALIKE_WEIGHTS = {"oil_stain": 1.0, "tar_stain": 1.0, "sealed_crack": 1.5, "tyre_mark": 1.0, "wet_patch": 0.5,
                     "puddle": 0.5, "debris": 0.5, "patch_seam": 1.0, "worn_paint": 0.5, "ghost_paint": 0.5}


def parse_weights(text: str | None, option: str = "--weights") -> dict[str, float]:
    """``pothole=2,crack=12`` -> {"pothole": 2.0, "crack": 12.0} (defect-type weights of the rules,
    or --label-range's metres)."""
    weights = {}
    for item in filter(None, (text or "").split(",")):
        kind, _, value = item.partition("=")
        try:
            weights[kind.strip()] = float(value)
        except ValueError:
            sys.exit(f"{option}: {item!r} is not NAME=NUMBER")
    return weights


def weighted_layout(src: Path, dst: Path, lookalikes: bool, weights: dict[str, float] | None = None,
                    models_per_type: int | None = None) -> Path:
    """A copy of ``src`` whose compose rules weight the look-alike types in (and, with
    ``weights``, the defect types as given; with ``models_per_type``, that many models a type:
    a size prior needs more than a layout's few draws to show its spread)."""
    layer = Sdf.Layer.FindOrOpen(str(src))
    out = Sdf.Layer.CreateNew(str(dst))
    out.TransferContent(layer)
    root = out.GetPrimAtPath(out.defaultPrim and f"/{out.defaultPrim}" or out.rootPrims[0].path)
    chosen = {**(LOOKALIKE_WEIGHTS if lookalikes else {}), **(weights or {})}
    if chosen:
        for kind, w in chosen.items():
            name = f"roadtwin:rules:weight:{kind}"
            spec = root.attributes.get(name) or Sdf.AttributeSpec(root, name, Sdf.ValueTypeNames.Double,
                                                                  Sdf.VariabilityVarying, True)
            spec.default = w
    if models_per_type:
        name = "roadtwin:rules:modelsPerType"
        spec = root.attributes.get(name) or Sdf.AttributeSpec(root, name, Sdf.ValueTypeNames.Int, Sdf.VariabilityVarying, True)
        spec.default = models_per_type
    out.Save()
    return dst


def scene_library(library: Path, dst: Path, shares: int, index: int, types=None) -> Path | None:
    """Every ``shares``-th asset of the photo library (offset by the scene), linked into ``dst``:
    each scene gets other real defects, and compose reads a fifth of a large library. ``types``:
    only assets of these defect types (``--photo-types``: the others stay parametric); None when
    no asset is left."""
    assets = sorted(p for p in library.glob("*.usda") if not p.name.endswith(".geom.usda"))
    if types is not None:
        assets = [a for a in assets if asset_type(a) in types]
    assets = assets[index % shares::shares]
    if not assets:
        return None
    dst.mkdir(parents=True)
    for asset in assets:
        for f in (asset, asset.with_name(f"{asset.stem}.geom.usda")):
            (dst / f.name).symlink_to(f.resolve())
    if (library / "textures").is_dir():
        (dst / "textures").symlink_to((library / "textures").resolve())
    return dst


@functools.lru_cache(maxsize=None)
def asset_type(asset: Path) -> str | None:
    """A library asset's ``roadtwin:defect:type`` (its interface only; each asset read once for all scenes)."""
    return read_interface(asset).attrs.get("roadtwin:defect:type")


def views(args) -> str:
    """render --views: the aimed share, the rest clear of defects, aimed defects --defect-distance ahead."""
    return f"defects:{args.defect_share}:clear" + (f":{args.defect_distance}" if args.defect_distance else "")


def class_map(args, work: Path) -> str:
    """The real frames' class map; with --no-camera a copy without its measured camera targets,
    with --label-range a copy whose [label_range_m] leaves farther defects unlabelled."""
    if not args.no_camera and not args.label_range:
        return "builtin:road_defects_br"
    from importlib import resources
    text = resources.files("roadtwin_core.render").joinpath("classmaps", "road_defects_br.toml").read_text()
    kept = [line for line in text.splitlines() if not (args.no_camera and line.startswith("camera_targets"))]
    if args.label_range:
        kept += ["", "[label_range_m]", *(f"{k} = {v}" for k, v in parse_weights(args.label_range, "--label-range").items())]
    path = work / "classmap_variant.toml"
    path.write_text("\n".join(kept) + "\n")
    return str(path)
