"""``roadtwin validate``, ``export`` and ``import``: options and what they print; the work is
:mod:`roadtwin_core.apps.stage`."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .._console import console
from ..params import PARAM_HELP, parse_param_options

__all__ = ["export", "import_command", "validate"]


def validate(stage: Path = typer.Argument(..., help="USD stage to check")) -> None:
    """Run pxr.UsdValidation on a stage and print the findings; exit 1 on errors."""
    from ..apps.stage import validate_town

    findings = validate_town(stage)
    for f in findings:
        console.print(f"{f.severity}: {f.validator}: {f.message} {' '.join(f.sites)}", highlight=False)
    errors = sum(f.severity == "Error" for f in findings)
    console.print(f"{stage}: {errors} error(s), {len(findings) - errors} other finding(s)")
    if errors:
        raise typer.Exit(1)


def export(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    format: str = typer.Option(..., "--format", "-f", help="exporter name: usdz, glb, obj, ply, ..."),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="output file (default: beside the stage)"),
) -> None:
    """Export a composed stage to another tool's format, keeping road and defects apart."""
    from ..apps.stage import export_stage

    path = export_stage(stage, format, out)
    console.print(f"wrote {path}")


def import_command(
    importer: str = typer.Argument(..., help="layout importer plugin, e.g. opendrive"),
    source: Path = typer.Argument(..., help="input map file"),
    out: Path = typer.Option(..., "-o", "--out", help="layout file to write (.usda)"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"importer {PARAM_HELP}"),
) -> None:
    """Import a foreign road network (e.g. OpenDRIVE) as a roadtwin layout."""
    from ..apps.stage import import_layout

    layout = import_layout(importer, source, out, parse_param_options(param))
    console.print(f"wrote {out}: {len(layout.segments)} segments")
