"""``roadtwin compose``: options, a progress bar and the summary table; the composing is
:func:`roadtwin_core.apps.compose.run.compose`."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from .._console import console, err_console
from ..atomic import output_path
from ..params import PARAM_HELP, parse_param_options

if TYPE_CHECKING:
    from ..apps.compose.run import ComposeResult

__all__ = ["compose"]


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
    props: str = typer.Option("default", "--props",
                              help="the roadside world (layers/props.usda): default | none | RULES.toml"),
    road_textures: Optional[Path] = typer.Option(None, "--road-textures", help="folder of road materials (roadtwin "
                                                 "reconstruct photo-surfaces): each becomes a roadMaterial variant"),
    road_material: Optional[str] = typer.Option(None, "--road-material", help="the roadMaterial variant selected "
                                                "(default asphalt; cobblestone, cement or a --road-textures name)"),
    defect_priors: Optional[str] = typer.Option(None, "--defect-priors", help="per-type parameter distributions "
                                                "drawn instead of the types' own ranges: builtin:road_defects_br "
                                                "(measured from its train labels) or a TOML file"),
) -> None:
    """Place defects on a layout, merge them into the road meshes and write a town stage."""
    from ..apps.compose.run import compose as run_compose

    output_path(out, "dir")
    merger_params = parse_param_options(param)
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
                             workers=workers, library_dir=library, merger_params=merger_params, props=props,
                             road_textures=road_textures, road_material=road_material,
                             defect_priors=defect_priors)
    _print_summary(result)


def _print_summary(result: ComposeResult) -> None:
    s = result.summary
    table = Table(title=f"composed {result.town}")
    table.add_column("item")
    table.add_column("value", justify="right")
    rows = [("segments", s["segments"]), ("defects", s["defects"]),
            *((f"  {t}", n) for t, n in s["defects_by_type"].items()),
            ("straddling defects", s["straddling_defects"]), ("triangles", s["triangles"]),
            ("road area (m²)", f"{s['road_area_m2']:.1f}"), ("defect area (m²)", f"{s['defect_area_m2']:.2f}"),
            ("defect volume (m³)", f"{s['defect_volume_m3']:.4f}"),
            ("props", s["props"]["instances"]),
            ("validation errors", s["validation"]["errors"]),
            ("time (s)", " / ".join(f"{k[:-2]} {v:.2f}" for k, v in s["timings_s"].items()))]
    for k, v in rows:
        table.add_row(k, str(v))
    console.print(table)
