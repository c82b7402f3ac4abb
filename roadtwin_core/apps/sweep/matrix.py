"""The sweep's run matrix: which runs to drive, from where, for how long, and simulating them.

Run matrix: for each crossing (a defect with a path through it, see ``roads.py``), each vehicle
parameter set, each lateral offset (meters the vehicle's centreline runs to the *left* of the
defect centre; default +track/2: the right wheels over the centre) and each speed, one run on the
road and its twin on the baseline road (defects filled in). Both batches go to the backend in one
``simulate`` call each.

Timing of a run (speed v, CG starting ``run_up`` = max(3 m, 1 s x v) before the front axle
reaches the defect): the front axle enters the footprint at t_front, the rear axle leaves it at
t_rear; the crossing window is [t_front - 0.5 s, t_rear + 1.5 s] and the run ends with it. Where
the road along the path is known to end (test roads exactly; towns from a 0.5 m occupancy grid of
the collision mesh over the wheel tracks), run-up and tail are shortened so every wheel stays on
the road (``window_clipped``). The twin run cancels what is left of the start transient in g.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ...errors import RoadtwinError
from ...vehicle import QuarterCarParams, Scenario, SimParams, Traces, VehicleParams, VehicleRun, offset_polyline

__all__ = ["KMH", "RunSpec", "SweepConfig", "build_matrix", "parse_offsets", "parse_speeds", "simulate_specs"]

KMH = 1 / 3.6


def parse_speeds(spec: str) -> list[float]:
    """``START:STOP:STEP`` (inclusive, km/h) or ``A,B,C``; every speed must be > 0."""
    text = str(spec).strip()
    try:
        if ":" in text:
            parts = [float(p) for p in text.split(":")]
            if len(parts) != 3:
                raise ValueError
            start, stop, step = parts
            if not all(math.isfinite(p) for p in parts):
                raise ValueError
            if step <= 0:
                raise RoadtwinError(f"speeds {spec!r}: step must be > 0")
            if stop < start:
                raise RoadtwinError(f"speeds {spec!r}: stop must be >= start")
            n = int(math.floor((stop - start) / step + 1e-9)) + 1
            if n > 1000:
                raise RoadtwinError(f"speeds {spec!r}: more than 1000 speeds")
            speeds = [start + i * step for i in range(n)]
        else:
            speeds = [float(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise RoadtwinError(f"speeds {spec!r}: expected START:STOP:STEP or a comma list, in km/h") from None
    if not speeds:
        raise RoadtwinError(f"speeds {spec!r}: no speeds")
    bad = [s for s in speeds if not (math.isfinite(s) and s > 0)]
    if bad:
        raise RoadtwinError(f"speeds {spec!r}: every speed must be > 0 km/h, got {bad[0]:g}")
    if max(speeds) > 300:
        raise RoadtwinError(f"speeds {spec!r}: {max(speeds):g} km/h is beyond a road vehicle (max 300)")
    return speeds


def parse_offsets(spec: str | None) -> list[float] | None:
    if spec is None or not str(spec).strip():
        return None
    try:
        vals = [float(p) for p in str(spec).split(",") if p.strip()]
    except ValueError:
        raise RoadtwinError(f"offsets {spec!r}: expected a comma list of meters") from None
    if not vals or not all(math.isfinite(v) and abs(v) <= 5.0 for v in vals):
        raise RoadtwinError(f"offsets {spec!r}: each offset must be a finite number of meters within +-5")
    return vals


@dataclass
class SweepConfig:
    speeds_kmh: list[float]
    vehicles: dict[str, Any] = field(default_factory=lambda: {"default_car": VehicleParams()})
    offsets_m: list[float] | None = None      # None: +track/2 of each vehicle (right wheels over the centre)
    sim: SimParams = field(default_factory=SimParams)
    run_up_s: float = 1.0
    run_up_min_m: float = 3.0
    pre_s: float = 0.5
    post_s: float = 1.5


@dataclass
class RunSpec:
    run_id: int
    defect: str
    defect_type: str
    speed_kmh: float
    offset_m: float
    vehicle: str
    path: np.ndarray
    s0: float
    duration: float
    window: tuple[float, float]
    t_front: float
    t_rear: float
    t_ref: float            # common reference duration of g_rms for this defect (slowest crossing)
    clipped: bool = False   # run-up or tail shortened to stay on the road


def _geometry(params) -> tuple[float, float, float]:
    """(CG to front axle, CG to rear axle, default offset) of a parameter set."""
    if isinstance(params, QuarterCarParams):
        return 0.0, 0.0, 0.0
    return params.cg_to_front_axle_m, params.cg_to_rear_axle_m, params.track_front_m / 2


def build_matrix(scenario: Scenario, config: SweepConfig) -> list[RunSpec]:
    if not config.speeds_kmh or min(config.speeds_kmh) <= 0:
        raise RoadtwinError("sweep: speeds must be > 0 km/h")
    vmin = min(config.speeds_kmh) * KMH
    specs: list[RunSpec] = []
    for c in scenario.crossings:
        e0, e1 = c.extent
        for vname, params in config.vehicles.items():
            a, b, default_off = _geometry(params)
            radius = getattr(params, "tire_radius_m", 0.3)
            t_ref = config.pre_s + (e1 - e0 + a + b) / vmin + config.post_s
            for off in (config.offsets_m if config.offsets_m is not None else [default_off]):
                path = offset_polyline(c.path, off)
                for kmh in config.speeds_kmh:
                    v = kmh * KMH
                    run_up = max(config.run_up_min_m, config.run_up_s * v)
                    clipped = False
                    if c.limits is not None:  # keep every wheel on the road: shorten the run-up / the tail
                        room = c.s_center + e0 - a - (c.limits[0] + b + radius + 0.2)
                        if room < run_up:
                            run_up, clipped = max(room, 0.0), True
                    s0 = c.s_center + e0 - a - run_up          # CG arclength at t = 0
                    t_front = run_up / v
                    t_rear = (c.s_center + e1 + b - s0) / v
                    w0, w1 = max(t_front - config.pre_s, 0.0), t_rear + config.post_s
                    if c.limits is not None:
                        t_end = (c.limits[1] - a - radius - 0.2 - s0) / v
                        if t_end < w1:
                            w1, clipped = t_end, True
                        if w1 <= t_rear or room < 0:
                            raise RoadtwinError(
                                f"sweep: defect {c.defect_id}: the road around it is too short to drive over it "
                                f"with every wheel on the road ({c.limits[1] - c.limits[0]:.1f} m along the path)")
                    specs.append(RunSpec(len(specs), c.defect_id, c.defect_type, float(kmh), float(off), vname, path,
                                         float(s0), float(w1 + 0.02), (float(w0), float(w1)),
                                         float(t_front), float(t_rear), float(t_ref), clipped))
    return specs


def simulate_specs(backend, scenario: Scenario, specs: list[RunSpec], config: SweepConfig,
                   progress: Callable[[str], None] | None = None) -> tuple[Traces, Traces]:
    runs = [VehicleRun(config.vehicles[s.vehicle], s.path, s.s0, s.speed_kmh * KMH, s.duration) for s in specs]
    if progress:
        progress(f"{backend.name}: {len(runs)} runs on the road with defects")
    tr = backend.simulate(scenario.road, runs, config.sim)
    if progress:
        progress(f"{backend.name}: {len(runs)} twin runs on the baseline road")
    tr_ref = backend.simulate(scenario.baseline, runs, config.sim)
    return tr, tr_ref

