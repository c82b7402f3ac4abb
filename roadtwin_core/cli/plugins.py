"""``roadtwin plugins [--params NAME]``: what the installed plugins registered, and their parameters."""
from __future__ import annotations

from typing import Optional

import typer
from rich.table import Table

from .._console import console
from ..contracts import params_class
from ..errors import RoadtwinError
from ..params import describe_params
from ..plugins import KINDS, PluginManager, get_plugin_manager

__all__ = ["plugins"]


def plugins(
    params: Optional[str] = typer.Option(None, "--params", metavar="NAME",
                                         help="print the parameters of every registered thing called NAME"),
) -> None:
    """List every plugin, its version, what it registered (with descriptions) and any load error."""
    pm = get_plugin_manager()
    info = pm.load_all()
    if params is not None:
        _print_params(pm, params)
        return
    table = Table(title="roadtwin plugins")
    for col in ("plugin", "version", "registered", "error"):
        table.add_column(col)
    for name in sorted(info):
        i = info[name]
        reg = "\n".join(f"{kind}: {thing} - {pm.registry(kind)[thing].description}"
                        for kind, names in sorted(i.registered.items()) for thing in names)
        table.add_row(name, i.version, reg or "-", f"[red]{i.error}[/]" if i.error else "")
    console.print(table)


def _print_params(pm: PluginManager, name: str) -> None:
    """``roadtwin plugins --params NAME``: each parameter, its type, default, bounds and doc."""
    found = [(kind, pm.registry(kind)[name]) for kind in KINDS if name in pm.registry(kind)]
    if not found:
        known = sorted({n for kind in KINDS for n in pm.registry(kind)})
        raise RoadtwinError(f"--params: no plugin registered anything called {name!r} (known: {', '.join(known) or 'none'})")
    for kind, thing in found:
        label = kind.replace("_", " ").rstrip("s")
        rows = describe_params(params_class(kind, thing))
        table = Table(title=f"{label} {name}: {thing.description}", title_justify="left")
        for col in ("parameter", "type", "default", "bounds", "doc"):
            table.add_column(col)
        for r in rows:
            lo, hi = r["lo"], r["hi"]
            bounds = (f"{lo} .. {hi}" if lo is not None and hi is not None else f">= {lo}" if lo is not None
                      else f"<= {hi}" if hi is not None else "")
            table.add_row(r["name"], r["type"], repr(r["default"]), bounds, r["doc"])
        console.print(table if rows else f"{label} {name}: no parameters", highlight=False)
