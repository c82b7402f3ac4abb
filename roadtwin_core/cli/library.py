"""``roadtwin library list|show|add``: options only; what they do is ``roadtwin_core.apps.library``.

The folder is ``--library`` / ``-l``, default ``$ROADTWIN_LIBRARY`` or ``./library``.

- ``list``: one table row per asset (name, type, depth, area, volume, source), read from the
  interface files without loading geometry; files that are not defect assets are named on stderr.
- ``show NAME``: every attribute of the asset's root prim, its labels and extent, plus the
  geometry (vertices, faces, boundary loop).
- ``add FILE``: validates that FILE reads as a defect asset (geometry included), then copies it
  and the payload layers it references into the folder atomically (``--force`` replaces an
  asset of the same name).

The sub-app turns a :class:`~roadtwin_core.RoadtwinError` into one line and exit code 2 itself,
so it behaves the same mounted in ``roadtwin`` or on its own.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape
from rich.table import Table

from .._console import console, err_console
from ..errors import RoadtwinError
from .errors import fail

library_app = typer.Typer(add_completion=False, no_args_is_help=True,
                          help="A folder of road model library assets (defect models): list, show, add.")
LIBRARY_HELP = "library folder (default $ROADTWIN_LIBRARY or ./library)"


def _fmt(v, digits: int = 4) -> str:
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return "-" if v is None else str(v)


@library_app.command("list")
def list_command(
    library: Optional[Path] = typer.Option(None, "-l", "--library", help=LIBRARY_HELP),
) -> None:
    """List the defect assets of a library folder."""
    from ..apps.library import library_folder, list_assets

    folder = library_folder(library)
    try:
        assets, skipped = list_assets(folder)
    except RoadtwinError as exc:
        fail(str(exc))
    table = Table(title=f"roadtwin library {folder}")
    for col, just in (("name", "left"), ("type", "left"), ("depth m", "right"), ("area m²", "right"),
                      ("volume m³", "right"), ("source", "left")):
        table.add_column(col, justify=just)
    for p, info in assets:
        a = info.attrs
        table.add_row(p.stem, _fmt(a.get("roadtwin:defect:type")), _fmt(a.get("roadtwin:defect:depthM")),
                      _fmt(a.get("roadtwin:defect:areaM2")), _fmt(a.get("roadtwin:defect:volumeM3")),
                      escape(_fmt(a.get("roadtwin:source"))))
    console.print(table)
    for s in skipped:
        err_console.print(f"[yellow]skipped:[/] {escape(s)}", highlight=False, soft_wrap=True)


@library_app.command("show")
def show_command(
    name: str = typer.Argument(..., help="asset name (file stem or prim name)"),
    library: Optional[Path] = typer.Option(None, "-l", "--library", help=LIBRARY_HELP),
) -> None:
    """Print an asset's attributes, labels, extent and geometry summary."""
    from ..apps.library import library_folder, show_asset

    try:
        asset = show_asset(library_folder(library), name)
    except RoadtwinError as exc:
        fail(str(exc))
    info, model = asset.interface, asset.model
    table = Table(title=f"{asset.path.stem} ({escape(str(asset.path))})", show_header=False)
    table.add_column("attribute")
    table.add_column("value")
    table.add_row("prim", info.name)
    for k in sorted(info.attrs):
        table.add_row(k, escape(_fmt(info.attrs[k], 6)))
    if info.extent:
        table.add_row("extent", escape(str([tuple(round(x, 4) for x in e) for e in info.extent])))
    table.add_row("payloads", escape(", ".join(info.payloads) or "-"))
    table.add_row("vertices", str(len(model.vertices)))
    table.add_row("faces", str(len(model.faces)))
    table.add_row("boundary loop", f"{len(model.boundary)} vertices")
    console.print(table)


@library_app.command("add")
def add_command(
    file: Path = typer.Argument(..., help="defect asset interface file (NAME.usda, its NAME.geom.usda beside it)"),
    library: Optional[Path] = typer.Option(None, "-l", "--library", help=LIBRARY_HELP),
    force: bool = typer.Option(False, "--force", help="replace an asset of the same name"),
) -> None:
    """Validate a defect asset and copy it (with its geometry payload) into the library."""
    from ..apps.library import add_asset, library_folder

    folder = library_folder(library)
    try:
        out = add_asset(file, folder, force)
    except RoadtwinError as exc:
        fail(str(exc))
    console.print(f"added [bold]{escape(out.stem)}[/] to {escape(str(folder))}", highlight=False)
