"""usdz exporter: the composed stage packaged as one file, layers kept.

``pxr.UsdUtils.CreateNewUsdzPackage`` gathers the root layer, its sublayers (semantics, physics,
defects, roads, the input layout), references, payloads and asset-valued attributes (the defect
library assets named by ``roadtwin:source``) and rewrites their paths into the package, so the
layered structure (and the ability to mute a layer) survives. Layers stay as they were written
(readable usda, plus the ``*.geom.usdc`` crate files holding the mesh arrays that the roads,
defects and markings layers sublayer); this is a plain usdz, not the ARKit profile (which
flattens to one usdc layer).

Before the package replaces the output it is opened again and must have the same default prim,
the same renderable meshes (with the same point counts) and the same defect prims (children of ``/<root>/Defects``) as the
source stage.
"""
from __future__ import annotations

from pathlib import Path

from pxr import Sdf, Tf, Usd, UsdGeom, UsdUtils

from roadtwin_core import RoadtwinError

from roadtwin_core.atomic import atomic_files
from ._stage import open_stage, renderable_prims


def _summary(stage: Usd.Stage) -> tuple[str, list[tuple[str, int]], list[str]]:
    """Default prim, renderable meshes with their point counts (a crate left out of the package
    keeps the prims but loses their points), defect prims."""
    root = stage.GetDefaultPrim()
    name = root.GetName() if root else ""
    group = stage.GetPrimAtPath(f"/{name}/Defects") if name else None
    defects = sorted(str(p.GetPath()) for p in group.GetChildren()) if group else []
    meshes = sorted((str(p.GetPath()), _point_count(p)) for p in renderable_prims(stage))
    return name, meshes, defects


def _point_count(prim: Usd.Prim) -> int:
    points = UsdGeom.Mesh(prim).GetPointsAttr().Get() if prim.IsA(UsdGeom.Mesh) else None
    return len(points) if points is not None else 0


class UsdzExporter:
    name = "usdz"
    suffix = ".usdz"
    description = "one-file USD package: every layer, library asset and payload of the stage"

    def export(self, stage_path: Path, out_path: Path) -> Path:
        stage_path, out_path = Path(stage_path), Path(out_path)
        source = open_stage(stage_path)
        want = _summary(source)
        if not want[1]:
            raise RoadtwinError(f"{stage_path}: no renderable meshes to export")
        del source
        if out_path.suffix.lower() != ".usdz":
            raise RoadtwinError(f"{out_path}: a usdz package must be named *.usdz (USD picks the format by suffix)")
        with atomic_files(out_path) as (tmp,):
            try:
                ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(stage_path.resolve())), str(tmp))
            except Tf.ErrorException as exc:
                raise RoadtwinError(f"{stage_path}: cannot package as usdz ({str(exc).strip().splitlines()[0]})") from None
            if not ok or not tmp.exists():
                raise RoadtwinError(f"{stage_path}: cannot package as usdz (UsdUtils.CreateNewUsdzPackage failed)")
            try:
                got = _summary(Usd.Stage.Open(str(tmp), Usd.Stage.LoadAll))
            except Tf.ErrorException:
                got = None
            if got != want:
                what = "does not open" if got is None else (
                    f"has {len(got[1])} renderable meshes and {len(got[2])} defects, "
                    f"the stage {len(want[1])} and {len(want[2])}")
                raise RoadtwinError(f"{stage_path}: usdz package {what}")
        return out_path
