"""``roadtwin library list|show|add``: a folder of defect library assets.

A library folder holds ``NAME.usda`` interface files (labels, ``roadtwin:defect:*`` attributes,
extent) that payload ``NAME.geom.usda`` (see :mod:`roadtwin_core.usd.library`); a composed town's
``OUT/library/`` is one. The folder is ``--library`` / ``-l``, default ``$ROADTWIN_LIBRARY`` or
``./library``.

- ``list``: one table row per asset (name, type, depth, area, volume, source), read from the
  interface files without loading geometry; files that are not defect assets are named on stderr.
- ``show NAME``: every attribute of the asset's root prim, its labels and extent, plus the
  geometry (vertices, faces, boundary loop) read through :func:`read_defect_asset`.
- ``add FILE``: validates that FILE reads as a defect asset (geometry included), then copies it
  and the payload layers it references into the folder: payloads first, interface last, each
  through a temporary file and ``os.replace``, so a reader never sees an interface whose
  geometry is missing; on any error the copies made so far are removed. An existing asset of
  the same name is refused unless ``--force``.

``cli.py`` registers the sub-app with::

    from .cli_library import library_app; app.add_typer(library_app, name="library")
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Optional

import typer
from .._console import console, err_console
from rich.markup import escape
from rich.table import Table

from ..errors import RoadtwinError

library_app = typer.Typer(add_completion=False, no_args_is_help=True,
                          help="A folder of road model library assets (defect models): list, show, add.")
_console, _err = console, err_console
GEOM_SUFFIX = ".geom.usda"


def _fail(message: str) -> None:
    _err.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def _folder(library: Optional[Path]) -> Path:
    return Path(library) if library is not None else Path(os.environ.get("ROADTWIN_LIBRARY", "library"))


def asset_files(folder: Path) -> list[Path]:
    """Interface files of a library folder (``*.usda`` / ``*.usd`` / ``*.usdc``, payloads excluded)."""
    if not folder.is_dir():
        raise RoadtwinError(f"{folder}: no such library folder")
    out = [p for p in sorted(folder.iterdir())
           if p.is_file() and p.suffix in (".usda", ".usd", ".usdc") and not p.name.endswith(GEOM_SUFFIX)
           and not p.name.startswith(".")]
    return out


def read_interface(path: Path) -> dict:
    """Root-prim attributes, labels and payload paths of an asset, geometry not loaded."""
    from pxr import Usd, UsdGeom

    from ..usd.checks import open_stage

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
    return {"name": root.GetName(), "attrs": attrs, "payloads": payloads,
            "extent": [tuple(float(x) for x in e) for e in extent] if extent else None}


def _fmt(v, digits: int = 4) -> str:
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return "-" if v is None else str(v)


@library_app.command("list")
def list_assets(
    library: Optional[Path] = typer.Option(None, "-l", "--library", help="library folder (default $ROADTWIN_LIBRARY or ./library)"),
) -> None:
    """List the defect assets of a library folder."""
    folder = _folder(library)
    try:
        files = asset_files(folder)
    except RoadtwinError as exc:
        _fail(str(exc))
    table = Table(title=f"roadtwin library {folder}")
    for col, just in (("name", "left"), ("type", "left"), ("depth m", "right"), ("area m²", "right"),
                      ("volume m³", "right"), ("source", "left")):
        table.add_column(col, justify=just)
    skipped = []
    for p in files:
        try:
            info = read_interface(p)
        except RoadtwinError as exc:
            skipped.append(str(exc))
            continue
        a = info["attrs"]
        table.add_row(p.stem, _fmt(a.get("roadtwin:defect:type")), _fmt(a.get("roadtwin:defect:depthM")),
                      _fmt(a.get("roadtwin:defect:areaM2")), _fmt(a.get("roadtwin:defect:volumeM3")),
                      escape(_fmt(a.get("roadtwin:source"))))
    _console.print(table)
    for s in skipped:
        _err.print(f"[yellow]skipped:[/] {escape(s)}", highlight=False, soft_wrap=True)


def _resolve(folder: Path, name: str) -> Path:
    files = asset_files(folder)
    for p in files:
        if p.stem == name or p.name == name:
            return p
    for p in files:  # by prim name
        try:
            if read_interface(p)["name"] == name:
                return p
        except RoadtwinError:
            continue
    known = ", ".join(p.stem for p in files[:12]) or "none"
    raise RoadtwinError(f"{folder}: no asset {name!r} (known: {known}{' ...' if len(files) > 12 else ''})")


@library_app.command("show")
def show(
    name: str = typer.Argument(..., help="asset name (file stem or prim name)"),
    library: Optional[Path] = typer.Option(None, "-l", "--library", help="library folder (default $ROADTWIN_LIBRARY or ./library)"),
) -> None:
    """Print an asset's attributes, labels, extent and geometry summary."""
    from ..usd.library import read_defect_asset

    folder = _folder(library)
    try:
        path = _resolve(folder, name)
        info = read_interface(path)
        model = read_defect_asset(path)
    except RoadtwinError as exc:
        _fail(str(exc))
    table = Table(title=f"{path.stem} ({escape(str(path))})", show_header=False)
    table.add_column("attribute")
    table.add_column("value")
    table.add_row("prim", info["name"])
    for k in sorted(info["attrs"]):
        table.add_row(k, escape(_fmt(info["attrs"][k], 6)))
    if info["extent"]:
        table.add_row("extent", escape(str([tuple(round(x, 4) for x in e) for e in info["extent"]])))
    table.add_row("payloads", escape(", ".join(info["payloads"]) or "-"))
    table.add_row("vertices", str(len(model.vertices)))
    table.add_row("faces", str(len(model.faces)))
    table.add_row("boundary loop", f"{len(model.boundary)} vertices")
    _console.print(table)


def _payload_files(src: Path, info: dict) -> list[Path]:
    out = []
    for ap in info["payloads"]:
        p = (src.parent / ap).resolve() if not Path(ap).is_absolute() else Path(ap)
        if Path(ap).is_absolute() or ".." in Path(ap).parts or "/" in ap.lstrip("./"):
            raise RoadtwinError(f"{src}: payload {ap!r} is not a file beside the asset; cannot copy it into a library")
        if not p.is_file():
            raise RoadtwinError(f"{src}: payload {ap!r} is missing")
        out.append(p)
    return out


def add_asset(src: Path, folder: Path, force: bool = False) -> Path:
    """Validate ``src`` and copy it (with its payloads) into ``folder`` atomically; returns the copy."""
    from ..usd.library import read_defect_asset

    src = Path(src)
    if not src.is_file():
        raise RoadtwinError(f"{src}: no such file")
    info = read_interface(src)
    read_defect_asset(src)  # geometry, boundary loop and flags must read too
    payloads = _payload_files(src, info)
    from ..atomic import output_path

    output_path(folder, "dir")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RoadtwinError(f"{folder}: cannot create the library folder ({exc.strerror})") from None
    targets = [(p, folder / p.name) for p in payloads] + [(src, folder / src.name)]
    if src.resolve().parent == folder.resolve():
        raise RoadtwinError(f"{src}: already in library {folder}")
    clash = [t for _, t in targets if t.exists()]
    if clash and not force:
        raise RoadtwinError(f"{folder}: {clash[0].name} already exists (use --force to replace it)")
    from ..atomic import atomic_files

    replaced = False
    try:
        with atomic_files(*(t for _, t in targets)) as tmps:
            for tmp, (s, _) in zip(tmps, targets):
                shutil.copyfile(s, tmp)
        replaced = True
        read_defect_asset(folder / src.name)
    except Exception as exc:
        if replaced and not clash:
            for _, t in targets:
                t.unlink(missing_ok=True)
        if isinstance(exc, RoadtwinError):
            raise
        raise RoadtwinError(f"{folder}: cannot add {src.name} ({type(exc).__name__}: {exc})") from None
    return folder / src.name


@library_app.command("add")
def add(
    file: Path = typer.Argument(..., help="defect asset interface file (NAME.usda, its NAME.geom.usda beside it)"),
    library: Optional[Path] = typer.Option(None, "-l", "--library", help="library folder (default $ROADTWIN_LIBRARY or ./library)"),
    force: bool = typer.Option(False, "--force", help="replace an asset of the same name"),
) -> None:
    """Validate a defect asset and copy it (with its geometry payload) into the library."""
    folder = _folder(library)
    try:
        out = add_asset(file, folder, force)
    except RoadtwinError as exc:
        _fail(str(exc))
    _console.print(f"added [bold]{escape(out.stem)}[/] to {escape(str(folder))}", highlight=False)
