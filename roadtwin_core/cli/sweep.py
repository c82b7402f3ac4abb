"""``roadtwin sweep``: vibration sweeps over a town's defects (or a straight ISO 8608 test road).

Options only: the text options are parsed here (speeds, offsets, tire sampling, ``--param``);
what the command does is :func:`roadtwin_core.apps.sweep.command.sweep_to_folder`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .._console import console, err_console
from ..params import PARAM_HELP, parse_param_options

__all__ = ["sweep"]


def sweep(
    stage: Optional[Path] = typer.Argument(None, help="composed town stage (town.usda); omit it with --surface"),
    out: Path = typer.Option(..., "-o", "--out", help="output directory (replaced atomically)"),
    backend: str = typer.Option("warp", "--backend", help="physics backend plugin: warp | pybullet | ..."),
    device: str = typer.Option("cpu", "--device", help="cpu | cuda | cuda:N (warp); pybullet is CPU only"),
    speeds: str = typer.Option("5:60:5", "--speeds", help="km/h: START:STOP:STEP (inclusive) or A,B,C"),
    defects: Optional[str] = typer.Option(None, "--defects", help="defect ids to cross, comma separated (default: all)"),
    vehicle: Optional[Path] = typer.Option(None, "--vehicle", help="vehicle file (.toml/.json); default: the built-in car"),
    surface: Optional[str] = typer.Option(None, "--surface",
                                          help="iso8608:CLASS or flat: a straight test road with the reference "
                                               "defects instead of a stage"),
    length: float = typer.Option(60.0, "--length", help="test road length (m), with --surface"),
    offsets: Optional[str] = typer.Option(None, "--offsets",
                                          help="lateral offsets (m) of the vehicle centreline left of the defect "
                                               "centre, comma separated (default: +track/2, right wheels over it)"),
    seed: int = typer.Option(0, "--seed", help="seed of the ISO 8608 test road"),
    dt: float = typer.Option(0.001, "--dt", help="integration step (s)"),
    imu_rate: float = typer.Option(500.0, "--imu-rate", help="IMU sample rate (Hz)"),
    tire: str = typer.Option("3x7+2", "--tire", help="tire contact sampling SLICESxARC_RAYS[+BISECTION_ROUNDS]"),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="write the PNG plots"),
    rerun: bool = typer.Option(False, "--rerun", help="also write a rerun recording (needs rerun-sdk)"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"physics backend {PARAM_HELP}"),
) -> None:
    """Drive vehicles over defects at several speeds; write g/aw per run, IMU traces, plots and a
    recommended speed per defect."""
    from ..apps.sweep import parse_offsets, parse_speeds
    from ..apps.sweep.command import sweep_to_folder
    from ..apps.sweep.report import print_report
    from ..apps.sweep.setup import sim_params

    speed_list = parse_speeds(speeds)

    def progress(msg: str) -> None:
        err_console.print(f"[dim]{msg}[/]", highlight=False)

    result = sweep_to_folder(out, speeds_kmh=speed_list, sim=sim_params(dt, imu_rate, device, tire), stage=stage,
                             surface=surface, backend=backend, vehicle=vehicle, offsets_m=parse_offsets(offsets),
                             length=length, seed=seed, defects=defects, backend_params=parse_param_options(param),
                             plots=plots, rerun=rerun, progress=progress)
    print_report(console, result, out, backend, len(speed_list))
