"""``run_sweep``: build the matrix, simulate it and its twins, compute the table and the
recommendations, write the outputs."""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable

from ...vehicle import Scenario
from .matrix import SweepConfig, build_matrix, simulate_specs
from .outputs import write_outputs
from .recommend import recommend
from .rows import compute_rows

__all__ = ["dataclass_dict", "run_sweep"]


def run_sweep(scenario: Scenario, backend, config: SweepConfig, outdir: Path | None = None, plots: bool = True,
              rerun: bool = False, progress: Callable[[str], None] | None = None) -> dict:
    """Build the matrix, simulate it and its twins, compute metrics and (optionally) write them."""
    config.sim.check(f"physics backend {backend.name}")
    specs = build_matrix(scenario, config)
    t0 = time.perf_counter()
    tr, tr_ref = simulate_specs(backend, scenario, specs, config, progress)
    wall = time.perf_counter() - t0
    rows = compute_rows(specs, tr, tr_ref, backend.name)
    recs = recommend(rows)
    sim_s = tr.meta["sim_s"] + tr_ref.meta["sim_s"]
    kern = tr.meta["wall_s"] + tr_ref.meta["wall_s"]
    summary = {"source": scenario.source, "backend": backend.name, "device": tr.meta.get("device"),
               "runs": len(specs), "defects": len(scenario.crossings), "speeds_kmh": config.speeds_kmh,
               "dt_s": config.sim.dt_s, "imu_rate_hz": config.sim.imu_rate_hz, "simulated_vehicle_s": sim_s,
               "simulation_wall_s": kern, "total_wall_s": wall, "realtime_factor": sim_s / max(kern, 1e-9),
               "triangles": int(len(scenario.road.faces)), "off_road_runs": int(sum(r["off_road"] for r in rows)),
               "vehicles": {k: dataclass_dict(v) for k, v in config.vehicles.items()},
               "g_definition": "peak over the crossing window of sqrt(wx'^2 + wy'^2 + 0.1 az'^2), primes = "
                               "deviation from the twin run on the road with the defect filled in; g_rms = "
                               "sqrt(integral of g^2 over the window / the slowest crossing's window length)"}
    result = {"rows": rows, "recommendations": recs, "specs": specs, "traces": tr, "baseline": tr_ref,
              "summary": summary}
    if outdir is not None:
        result["files"] = write_outputs(Path(outdir), rows, recs, specs, tr, tr_ref, summary, plots, rerun)
    return result


def dataclass_dict(obj) -> dict:
    return dataclasses.asdict(obj) if dataclasses.is_dataclass(obj) else dict(obj)
