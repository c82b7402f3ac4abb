"""``roadtwin sweep``: vibration sweeps over a town's defects (or a straight ISO 8608 test road).

The command function lives here so the CLI module stays small; ``cli.py`` registers it with::

    from .cli_sweep import sweep; app.command()(sweep)

Heavy imports (the physics backend, numpy work, matplotlib) happen inside the function.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from ._console import console, err_console
from rich.table import Table

from .errors import RoadtwinError

_console, _err = console, err_console


def parse_tire(spec: str) -> tuple[int, int, int]:
    import re

    m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*(?:\+\s*(\d+))?\s*", str(spec))
    if not m:
        raise RoadtwinError(f"sweep: --tire {spec!r}: expected SLICESxARC_RAYS[+ROUNDS], e.g. 3x7+2")
    return int(m.group(1)), int(m.group(2)), int(m.group(3) or 0)


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
) -> None:
    """Drive vehicles over defects at several speeds; write g/aw per run, IMU traces, plots and a
    recommended speed per defect."""
    from .atomic import atomic_output_dir
    from .usd.checks import output_path
    from .plugins import get_plugin_manager
    from .vehicle import (SimParams, SweepConfig, VehicleParams, load_full_vehicle, parse_offsets,
                          parse_speeds, run_sweep)
    from .vehicle.roads import load_town_scenario, straight_road_scenario

    output_path(out, "dir")
    if (stage is None) == (surface is None):
        raise RoadtwinError("sweep: give either a STAGE or --surface iso8608:CLASS (not both, not neither)")
    speed_list = parse_speeds(speeds)
    offset_list = parse_offsets(offsets)
    params = load_full_vehicle(vehicle, VehicleParams())
    nl, na, refine = parse_tire(tire)
    sim = SimParams(dt_s=dt, imu_rate_hz=imu_rate, device=device, tire_slices=nl, tire_arc_samples=na,
                    tire_refine=refine).check("sweep")
    engine = get_plugin_manager().get("physics_backends", backend)
    if seed < 0:
        raise RoadtwinError(f"sweep: seed must be >= 0, got {seed}")
    ids = [d.strip() for d in defects.split(",") if d.strip()] if defects else None
    if defects is not None and not ids:
        raise RoadtwinError(f"sweep: --defects {defects!r} names no defect")
    if surface is not None:
        scenario = straight_road_scenario(length, None if surface.strip().lower() == "flat" else surface, seed)
        scenario = scenario.select(ids)
    else:
        if not stage.exists():
            raise RoadtwinError(f"{stage}: no such file")
        scenario = load_town_scenario(stage, ids)
    config = SweepConfig(speeds_kmh=speed_list, vehicles={params.name: params}, offsets_m=offset_list, sim=sim)

    def progress(msg: str) -> None:
        _err.print(f"[dim]{msg}[/]", highlight=False)

    with atomic_output_dir(out) as tmp:
        result = run_sweep(scenario, engine, config, outdir=tmp, plots=plots, rerun=rerun, progress=progress)
    s = result["summary"]
    table = Table(title=f"sweep: {len(scenario.crossings)} defect(s) x {len(speed_list)} speed(s) on {backend}")
    for col in ("defect", "type", "recommended km/h", "g there", "g max (at km/h)", "comfortable up to", "note"):
        table.add_column(col)
    for r in result["recommendations"][:50]:
        fmt = (lambda v: "-" if v is None else f"{v:.3g}")
        table.add_row(str(r["defect"]), str(r.get("defect_type", "")), fmt(r["recommended_speed_kmh"]),
                      fmt(r["g_at_recommended"]), f"{fmt(r.get('g_max'))} ({fmt(r.get('speed_of_g_max_kmh'))})",
                      fmt(r["max_comfortable_speed_kmh"]), str(r["note"]))
    _console.print(table)
    _console.print(f"{s['runs']} runs + {s['runs']} twin runs, {s['simulated_vehicle_s']:.1f} vehicle-s simulated in "
                   f"{s['simulation_wall_s']:.2f} s on {s['device']} (real-time factor {s['realtime_factor']:.1f}x); "
                   f"wrote {out}", highlight=False)
    for note in s.get("notes", []):
        _console.print(f"note: {note}", highlight=False)
    if s["off_road_runs"]:
        _console.print(f"note: {s['off_road_runs']} run(s) left the road (see the off_road column)", highlight=False)
