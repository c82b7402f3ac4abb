"""``roadtwin export`` and ``roadtwin import``: a composed stage out to another tool's format
through an exporter plugin, a foreign road network in as a layout through an importer plugin."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pxr import Sdf

from ...atomic import atomic_files, output_path
from ...errors import RoadtwinError
from ...model import TownLayout
from ...params import apply_params
from ...plugins import PluginManager, get_plugin_manager
from ...usd.checks import open_stage
from ...usd.stage import check_stage_meshes
from ...usd.layout_io import write_layout

__all__ = ["export_stage", "import_layout"]


def export_stage(stage: str | Path, format: str, out: str | Path | None = None, *,
                 pm: PluginManager | None = None) -> Path:
    """Export a composed stage with the exporter called ``format`` to ``out`` (default: beside the
    stage, with the exporter's suffix); returns the path written."""
    stage = Path(stage)
    exporter = (pm or get_plugin_manager()).get("exporters", format)
    # unreadable, badly composed or malformed input: one line naming it
    check_stage_meshes(open_stage(stage, "composed town stage"), stage)
    target = output_path(out or stage.with_suffix(exporter.suffix))
    return exporter.export(stage, target)


def import_layout(importer: str, source: str | Path, out: str | Path, params: dict[str, Any] | None = None, *,
                  pm: PluginManager | None = None) -> TownLayout:
    """Import ``source`` with the layout importer called ``importer`` (``params``: values for its
    ``Params``) and write the layout to ``out`` (a USD file) atomically; returns the layout."""
    source, out = Path(source), Path(out)
    imp = (pm or get_plugin_manager()).get("layout_importers", importer)
    checked = apply_params(imp.Params, params or {}, f"layout importer {importer}")
    if not source.exists():
        raise RoadtwinError(f"{source}: no such file")
    if Sdf.FileFormat.FindByExtension(out.suffix.lstrip(".").lower() or "-") is None:
        raise RoadtwinError(f"{out}: a layout must be a USD file (.usda, .usd or .usdc)")
    output_path(out)
    layout = imp.load(source, checked)
    with atomic_files(out) as (tmp,):
        write_layout(layout, tmp, f"roadtwin layout imported from {source.name} by {importer}")
    return layout
