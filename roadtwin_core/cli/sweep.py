"""``roadtwin sweep``: vibration sweeps over a town's defects (or a straight ISO 8608 test road).

Options only: what the command does is ``roadtwin_core.apps.sweep``. ``cli.py`` registers it with::

    from .cli_sweep import sweep; app.command()(sweep)

Heavy imports (the physics backend, numpy work, matplotlib) happen inside the function.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from .._console import console, err_console

from ..errors import RoadtwinError
from ..params import PARAM_HELP, cli_params

_console, _err = console, err_console


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
    from ..apps.sweep import SweepConfig, parse_offsets, parse_speeds, run_sweep
    from ..apps.sweep.report import print_report
    from ..apps.sweep.setup import load_scenario, sim_params
    from ..atomic import atomic_output_dir
    from ..plugins import get_plugin_manager
    from ..atomic import output_path
    from ..vehicle import VehicleParams, load_full_vehicle

    output_path(out, "dir")
    if (stage is None) == (surface is None):
        raise RoadtwinError("sweep: give either a STAGE or --surface iso8608:CLASS (not both, not neither)")
    speed_list = parse_speeds(speeds)
    offset_list = parse_offsets(offsets)
    params = load_full_vehicle(vehicle, VehicleParams())
    sim = sim_params(dt, imu_rate, device, tire)
    sim = cli_params(param, sim, f"physics backend {backend}").check("sweep")
    engine = get_plugin_manager().get("physics_backends", backend)
    scenario = load_scenario(stage, surface, length, seed, defects)
    config = SweepConfig(speeds_kmh=speed_list, vehicles={params.name: params}, offsets_m=offset_list, sim=sim)

    def progress(msg: str) -> None:
        _err.print(f"[dim]{msg}[/]", highlight=False)

    with atomic_output_dir(out) as tmp:
        result = run_sweep(scenario, engine, config, outdir=tmp, plots=plots, rerun=rerun, progress=progress)
    print_report(_console, result, out, backend, len(speed_list))
