"""``roadtwin sweep`` as one call: a scenario (a town's defects or a straight test road), a vehicle
and a physics backend set up from the command's values, then :func:`~.run.run_sweep` into an
output folder written whole or not at all."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ...atomic import atomic_output_dir, output_path
from ...errors import RoadtwinError
from ...params import apply_params
from ...plugins import PluginManager, get_plugin_manager
from ...vehicle import SimParams, VehicleParams, load_full_vehicle
from .matrix import SweepConfig
from .run import run_sweep
from .setup import load_scenario

__all__ = ["sweep_to_folder"]


def sweep_to_folder(out: str | Path, *, speeds_kmh: list[float], sim: SimParams, stage: str | Path | None = None,
                    surface: str | None = None, backend: str = "warp", vehicle: VehicleParams | str | Path | None = None,
                    offsets_m: list[float] | None = None, length: float = 60.0, seed: int = 0,
                    defects: str | None = None, backend_params: dict[str, Any] | None = None, plots: bool = True,
                    rerun: bool = False, progress: Callable[[str], None] | None = None,
                    pm: PluginManager | None = None) -> dict:
    """Sweep the defects of a town ``stage`` or of a straight test road ``surface`` (one of them)
    and write the outputs to ``out``; returns :func:`~.run.run_sweep`'s result. ``vehicle``: a
    :class:`~roadtwin_core.vehicle.VehicleParams` or a vehicle file (default: the built-in car);
    ``backend_params``: values set on ``sim`` for the backend (``--param``), checked like the rest."""
    output_path(out, "dir")
    if (stage is None) == (surface is None):
        raise RoadtwinError("sweep: give either a STAGE or --surface iso8608:CLASS (not both, not neither)")
    car = vehicle if isinstance(vehicle, VehicleParams) else load_full_vehicle(vehicle, VehicleParams())
    if backend_params:
        sim = apply_params(sim, backend_params, f"physics backend {backend}").check("sweep")
    engine = (pm or get_plugin_manager()).get("physics_backends", backend)
    scenario = load_scenario(None if stage is None else Path(stage), surface, length, seed, defects)
    config = SweepConfig(speeds_kmh=speeds_kmh, vehicles={car.name: car}, offsets_m=offsets_m, sim=sim)
    with atomic_output_dir(out) as tmp:
        return run_sweep(scenario, engine, config, outdir=tmp, plots=plots, rerun=rerun, progress=progress)
