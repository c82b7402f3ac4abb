"""The ``roadtwin`` command line (typer + rich). Bad input: one line on stderr, exit code 2."""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Optional

import typer
from .._console import console, err_console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from ..errors import RoadtwinError
from ..params import PARAM_HELP

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="roadtwin: simulation-ready digital twins of roads with their defects, as OpenUSD.")


def _fail(message: str, code: int = 2) -> None:
    from rich.markup import escape

    # The message is plain text: a path or value with [brackets] must not be read as markup.
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


@app.command()
def plugins(
    params: Optional[str] = typer.Option(None, "--params", metavar="NAME",
                                         help="print the parameters of every registered thing called NAME"),
) -> None:
    """List every plugin, its version, what it registered (with descriptions) and any load error."""
    from ..plugins import get_plugin_manager

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


def _print_params(pm, name: str) -> None:
    """``roadtwin plugins --params NAME``: each parameter, its type, default, bounds and doc."""
    from ..contracts import params_class
    from ..params import describe_params
    from ..plugins import KINDS

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


@app.command()
def compose(
    layout: Path = typer.Argument(..., help="town layout (USD) with road segments and rules"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    defects: Optional[int] = typer.Option(None, "--defects", help="number of defect instances"),
    seed: Optional[int] = typer.Option(None, "--seed", help="random seed (same seed, same bytes)"),
    merger: Optional[str] = typer.Option(None, "--merger", help="merger plugin name (cdt, ...)"),
    surface: Optional[str] = typer.Option(None, "--surface", help="flat | flat:Z | iso8608:CLASS[:DX]"),
    preview: bool = typer.Option(True, help="write preview.png"),
    executor: str = typer.Option("local", "--executor", help="local (process pool) | serial | ray"),
    ray_address: Optional[str] = typer.Option(None, "--ray-address", help="Ray cluster address (default: start a local one)"),
    workers: Optional[int] = typer.Option(None, "--workers", help="worker processes (default: all cores)"),
    library: Optional[Path] = typer.Option(None, "--library", help="folder of defect assets mixed with the parametric models"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"merger {PARAM_HELP}"),
) -> None:
    """Place defects on a layout, merge them into the road meshes and write a town stage."""
    from ..apps.compose.run import compose as run_compose
    from ..params import parse_param_options
    from ..atomic import output_path

    output_path(out, "dir")

    # Only on a terminal: rich's transient Live still prints a blank line to a pipe or file, and
    # bad input must leave exactly one line on stderr.
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        tasks: dict[str, int] = {}

        def report(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(f"{stage} segments" if stage == "merge" else stage, total=total)
            bar.update(tasks[stage], completed=done)

        result = run_compose(layout, out, defects=defects, seed=seed, merger=merger, surface=surface,
                             progress=report, preview=preview, executor=executor, ray_address=ray_address,
                             workers=workers, library_dir=library, merger_params=parse_param_options(param))
    s = result.summary
    table = Table(title=f"composed {result.town}")
    table.add_column("item")
    table.add_column("value", justify="right")
    rows = [("segments", s["segments"]), ("defects", s["defects"]),
            *((f"  {t}", n) for t, n in s["defects_by_type"].items()),
            ("straddling defects", s["straddling_defects"]), ("triangles", s["triangles"]),
            ("road area (m²)", f"{s['road_area_m2']:.1f}"), ("defect area (m²)", f"{s['defect_area_m2']:.2f}"),
            ("defect volume (m³)", f"{s['defect_volume_m3']:.4f}"),
            ("validation errors", s["validation"]["errors"]),
            ("time (s)", " / ".join(f"{k[:-2]} {v:.2f}" for k, v in s["timings_s"].items()))]
    for k, v in rows:
        table.add_row(k, str(v))
    console.print(table)


@app.command()
def validate(stage: Path = typer.Argument(..., help="USD stage to check")) -> None:
    """Run pxr.UsdValidation on a stage and print the findings; exit 1 on errors."""
    from ..usd.checks import check_stage_meshes, open_stage
    from ..usd.validate import validate_stage

    # unreadable, badly composed or malformed input: one line, exit 2 (the findings are for the rest)
    check_stage_meshes(open_stage(stage, default_prim=False), stage)
    findings = validate_stage(stage)
    for f in findings:
        console.print(f"{f.severity}: {f.validator}: {f.message} {' '.join(f.sites)}", highlight=False)
    errors = sum(f.severity == "Error" for f in findings)
    console.print(f"{stage}: {errors} error(s), {len(findings) - errors} other finding(s)")
    if errors:
        raise typer.Exit(1)


@app.command()
def export(
    stage: Path = typer.Argument(..., help="composed town stage (town.usda)"),
    format: str = typer.Option(..., "--format", "-f", help="exporter name: usdz, glb, obj, ply, ..."),
    out: Optional[Path] = typer.Option(None, "-o", "--out", help="output file (default: beside the stage)"),
) -> None:
    """Export a composed stage to another tool's format, keeping road and defects apart."""
    from ..atomic import output_path
    from ..plugins import get_plugin_manager
    from ..usd.checks import check_stage_meshes, open_stage

    exporter = get_plugin_manager().get("exporters", format)
    # unreadable, badly composed or malformed input: one line naming it, exit 2
    check_stage_meshes(open_stage(stage, "composed town stage"), stage)
    target = output_path(out or stage.with_suffix(exporter.suffix))
    path = exporter.export(stage, target)
    console.print(f"wrote {path}")


@app.command("import")
def import_layout(
    importer: str = typer.Argument(..., help="layout importer plugin, e.g. opendrive"),
    source: Path = typer.Argument(..., help="input map file"),
    out: Path = typer.Option(..., "-o", "--out", help="layout file to write (.usda)"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"importer {PARAM_HELP}"),
) -> None:
    """Import a foreign road network (e.g. OpenDRIVE) as a roadtwin layout."""
    from pxr import Sdf

    from ..params import cli_params
    from ..plugins import get_plugin_manager
    from ..atomic import output_path
    from ..usd.layout_io import write_layout

    imp = get_plugin_manager().get("layout_importers", importer)
    params = cli_params(param, imp.Params, f"layout importer {importer}")
    if not source.exists():
        raise RoadtwinError(f"{source}: no such file")
    if Sdf.FileFormat.FindByExtension(out.suffix.lstrip(".").lower() or "-") is None:
        raise RoadtwinError(f"{out}: a layout must be a USD file (.usda, .usd or .usdc)")
    output_path(out)
    layout = imp.load(source, params)
    from ..atomic import atomic_files

    with atomic_files(out) as (tmp,):
        write_layout(layout, tmp, f"roadtwin layout imported from {source.name} by {importer}")
    console.print(f"wrote {out}: {len(layout.segments)} segments")


from .render import render as _render  # noqa: E402  (subcommands live in their own modules)

app.command("render")(_render)
from .render import rig_app as _rig_app  # noqa: E402

app.add_typer(_rig_app, name="rig")

from .plan import plan as _plan  # noqa: E402

app.command("plan")(_plan)

from .sweep import sweep as _sweep  # noqa: E402

app.command("sweep")(_sweep)

from .library import library_app  # noqa: E402

app.add_typer(library_app, name="library")

from .reconstruct import reconstruct_app  # noqa: E402

app.add_typer(reconstruct_app, name="reconstruct")


def main() -> None:
    try:
        rc = app(standalone_mode=False)
        if isinstance(rc, int) and rc:
            sys.exit(rc)
    except RoadtwinError as exc:
        _safe_fail(str(exc))
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        _safe_fail("aborted", 130)
    except Exception as exc:  # click usage errors and the like
        if _is_click_error(exc):
            # a usage error is the user's mistake: one line naming the option, exit 2
            message = " ".join(exc.format_message().split())
            _safe_fail(f"{message} (see roadtwin --help)", 2)
        if os.environ.get("ROADTWIN_DEBUG"):
            raise
        _safe_fail(f"internal error: {type(exc).__name__}: {exc} (set ROADTWIN_DEBUG=1 for a traceback)", 1)


def _is_click_error(exc: Exception) -> bool:
    """click's own exceptions; typer >= 0.16 ships a private copy of click, so match by class
    name along the MRO rather than by ``isinstance(exc, click.ClickException)``."""
    return any(c.__name__ == "ClickException" for c in type(exc).__mro__) and hasattr(exc, "format_message")


def _safe_fail(message: str, code: int = 2) -> None:
    try:
        _fail(message, code)
    except typer.Exit:
        sys.exit(code)


if __name__ == "__main__":
    main()
