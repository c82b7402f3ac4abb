"""Vibration sweeps: speeds x defects x lateral offsets x vehicle parameter sets, on any physics
backend, with a tidy table, IMU traces, plots and a recommended speed per defect.

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

Crossing metrics (see ``metrics.py``): ``g`` = peak of g(t) over the window. Why the peak: a
pothole crossing is a transient shock, and ISO 2631-1 (6.3) warns that the basic RMS method can
understate such events and adds peak-type measures (MTVV, VDV); the vibration degree has no
standard weighting, so its maximum over the crossing is used. Each IMU sample is already a mean
over its interval (2 ms at 500 Hz), so the peak does not depend on the time step. ``g_rms`` =
sqrt(integral of g^2 over the window / T_ref) with T_ref the window length of the slowest speed
of that defect (g' is 0 outside a run's own window), i.e. the energy of g, comparable across
speeds. ``aw``, ``rms_az``, ``peak_az`` are over the run's own window.

Outputs (``write_outputs``): ``runs.csv`` (+ ``runs.parquet`` when pyarrow is installed), one row
per vehicle run with backend, defect, type, speed (km/h and m/s), lateral offset, vehicle, the
crossing metrics g, g_rms, aw, comfort band, rms_az, peak_az, the whole-run ones (run_*), the
window and whether it was clipped, and whether the vehicle left the road; ``recommendations.csv`` / ``.json``; ``traces.npz`` (IMU of
every run and its twin); ``g_vs_speed.png``; ``imu_<defect>.png`` (wx, wy, az of one crossing at a
few speeds, the paper's figure); ``summary.json``; ``sweep.rrd`` with ``rerun=True`` when
rerun-sdk is installed.

Recommended speed per (defect, offset, vehicle): the fastest swept speed whose g is within 25 % of
the least g of the sweep (so a deep pothole gets "slow down", a small one whose g falls again at
speed may get "keep going"). Also reported: the fastest swept speed whose crossing stays at most
"a little uncomfortable" (aw < 0.561 m/s^2, see ``metrics.py``), or none, and where g peaks.
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import RoadtwinError
from .metrics import BAND_EDGES, window_metrics
from .roads import Scenario, offset_polyline
from .vehicle import QuarterCarParams, SimParams, Traces, VehicleParams, VehicleRun

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


def compute_rows(specs: list[RunSpec], tr: Traces, tr_ref: Traces, backend: str) -> list[dict]:
    rows = []
    t = np.asarray(tr.t)
    for s in specs:
        i = s.run_id
        m = window_metrics(t, tr.acc[i], tr.gyro[i], s.window, tr_ref.acc[i], tr_ref.gyro[i])
        settle = (0.5 * s.t_front, float(t[-1]))   # the whole run from half-way through the run-up
        mr = window_metrics(t, tr.acc[i], tr.gyro[i], settle, tr_ref.acc[i], tr_ref.gyro[i])
        g_rms = math.sqrt(m["g_energy"] / s.t_ref) if np.isfinite(m["g_energy"]) else float("nan")
        rows.append({"run_id": i, "backend": backend, "defect": s.defect, "defect_type": s.defect_type,
                     "speed_kmh": round(s.speed_kmh, 6), "speed_ms": round(s.speed_kmh * KMH, 6),
                     "lateral_offset_m": s.offset_m, "vehicle": s.vehicle,
                     "g": m["g_peak"], "g_rms": g_rms, "aw": m["aw"], "comfort": m["comfort"],
                     "rms_az": m["rms_az"], "peak_az": m["peak_az"],
                     "run_g": mr["g_peak"], "run_aw": mr["aw"], "run_rms_az": mr["rms_az"], "run_peak_az": mr["peak_az"],
                     "window_t0_s": s.window[0], "window_t1_s": s.window[1], "window_clipped": s.clipped,
                     "off_road": bool(tr.off_road[i] or tr_ref.off_road[i])})
    return rows


def recommend(rows: list[dict], tolerance: float = 0.25) -> list[dict]:
    """Per (defect, offset, vehicle): the fastest swept speed whose g is within ``tolerance``
    (25 %) of the least g of the sweep, and the fastest speed that stays at most "a little
    uncomfortable" (aw < 0.561 m/s^2)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["defect"], r["lateral_offset_m"], r["vehicle"]), []).append(r)
    out = []
    for (defect, off, veh), rs in groups.items():
        ok = [r for r in rs if np.isfinite(r["g"]) and not r["off_road"]]
        if not ok:
            out.append({"defect": defect, "defect_type": rs[0]["defect_type"], "lateral_offset_m": off, "vehicle": veh,
                        "recommended_speed_kmh": None, "g_at_recommended": None, "slowest_speed_kmh": None,
                        "g_at_slowest": None, "g_min": None, "g_max": None, "max_comfortable_speed_kmh": None,
                        "note": "no valid run (every run left the road or produced no samples)"})
            continue
        by_speed = sorted(ok, key=lambda r: r["speed_kmh"])
        gmin = min(r["g"] for r in ok)
        best = max((r for r in ok if r["g"] <= gmin * (1 + tolerance)), key=lambda r: r["speed_kmh"])
        comfy = [r["speed_kmh"] for r in ok if np.isfinite(r["aw"]) and r["aw"] < BAND_EDGES[1]]
        peak = max(ok, key=lambda r: r["g"])
        if peak is by_speed[-1]:
            note = "g is highest at the top speed: slow down"
        elif peak is by_speed[0]:
            note = "g is highest at the lowest speed: a higher speed reduces it"
        else:
            note = (f"g peaks at {peak['speed_kmh']:g} km/h; above it a higher speed reduces g "
                    f"({peak['g']:.3g} -> {by_speed[-1]['g']:.3g} at {by_speed[-1]['speed_kmh']:g} km/h)")
        out.append({"defect": defect, "defect_type": rs[0]["defect_type"], "lateral_offset_m": off, "vehicle": veh,
                    "recommended_speed_kmh": best["speed_kmh"], "g_at_recommended": best["g"],
                    "slowest_speed_kmh": by_speed[0]["speed_kmh"], "g_at_slowest": by_speed[0]["g"],
                    "g_min": gmin, "g_max": peak["g"], "speed_of_g_max_kmh": peak["speed_kmh"],
                    "max_comfortable_speed_kmh": max(comfy) if comfy else None, "note": note})
    return out


# ----------------------------------------------------------------------------- outputs
def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        path.write_text("")
        return
    keys = list(rows[0].keys())
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r[k] is None else r[k]) for k in keys})


def _write_parquet(path: Path, rows: list[dict]) -> bool:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    pq.write_table(pa.Table.from_pylist(rows), path)
    return True


def plot_g_vs_speed(path: Path, rows: list[dict], recs: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=110)
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["defect"], r["lateral_offset_m"], r["vehicle"]), []).append(r)
    multi = len({k[1:] for k in groups}) > 1
    for key, rs in list(groups.items())[:24]:
        rs = sorted(rs, key=lambda r: r["speed_kmh"])
        label = key[0] if not multi else f"{key[0]} ({key[1]:+.2f} m, {key[2]})"
        line, = ax.plot([r["speed_kmh"] for r in rs], [r["g"] for r in rs], "o-", ms=3, label=label)
        rec = next((c for c in recs if (c["defect"], c["lateral_offset_m"], c["vehicle"]) == key), None)
        if rec and rec["recommended_speed_kmh"] is not None:
            ax.plot([rec["recommended_speed_kmh"]], [rec["g_at_recommended"]], "*", ms=12, color=line.get_color())
    ax.set_xlabel("speed (km/h)")
    ax.set_ylabel("vibration degree g (peak over the crossing)")
    ax.set_title("g vs speed per defect (star: recommended speed)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_crossing(path: Path, defect: str, specs: list[RunSpec], tr: Traces, tr_ref: Traces) -> None:
    """wx, wy, az of one defect's crossing at up to four speeds (time from the front axle's entry)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mine = [s for s in specs if s.defect == defect]
    if not mine:
        return
    first = (mine[0].offset_m, mine[0].vehicle)
    mine = sorted([s for s in mine if (s.offset_m, s.vehicle) == first], key=lambda s: s.speed_kmh)
    pick = [mine[int(round(k))] for k in np.linspace(0, len(mine) - 1, min(4, len(mine)))]
    fig, axes = plt.subplots(3, 1, figsize=(8, 6.5), dpi=110, sharex=True)
    t = np.asarray(tr.t)
    for s in pick:
        i = s.run_id
        tt = t - s.t_front
        m = (t >= s.window[0]) & (t <= s.window[1])
        axes[0].plot(tt[m], tr.gyro[i, m, 0], lw=0.8, label=f"{s.speed_kmh:g} km/h")
        axes[1].plot(tt[m], tr.gyro[i, m, 1], lw=0.8)
        axes[2].plot(tt[m], tr.acc[i, m, 2], lw=0.8)
    for ax, lab in zip(axes, ("wx roll rate (rad/s)", "wy pitch rate (rad/s)", "az specific force (m/s²)")):
        ax.set_ylabel(lab, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=4)
    axes[0].set_title(f"IMU while crossing {defect} ({pick[0].defect_type})")
    axes[2].set_xlabel("time from the front axle reaching the defect (s)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_rerun(path: Path, specs: list[RunSpec], tr: Traces, limit: int = 16, every: int = 5) -> str:
    """Log az, wx, wy of the first ``limit`` runs (every ``every``-th IMU sample) to a .rrd file;
    says why when it cannot (rerun-sdk >= 0.23, with fallbacks for older names; tested with 0.41)."""
    try:
        import rerun as rr
    except ImportError:
        return "rerun-sdk is not installed: no rerun recording written (pip install rerun-sdk)"
    rr.init("roadtwin_sweep", spawn=False)
    rr.save(str(path))
    t = np.asarray(tr.t)
    scalar = getattr(rr, "Scalars", None) or getattr(rr, "Scalar")
    for s in specs[:limit]:
        base = f"runs/{s.defect}/{s.speed_kmh:g}kmh_{s.offset_m:+.2f}m_{s.vehicle}"
        for k in range(0, len(t), every):
            if not np.isfinite(tr.acc[s.run_id, k, 2]):
                break
            if hasattr(rr, "set_time"):
                rr.set_time("t", duration=float(t[k]))
            else:  # older SDKs
                rr.set_time_seconds("t", float(t[k]))
            rr.log(f"{base}/az", scalar(float(tr.acc[s.run_id, k, 2])))
            rr.log(f"{base}/wx", scalar(float(tr.gyro[s.run_id, k, 0])))
            rr.log(f"{base}/wy", scalar(float(tr.gyro[s.run_id, k, 1])))
    return f"wrote {path.name}"


def write_outputs(outdir: Path, rows: list[dict], recs: list[dict], specs: list[RunSpec], tr: Traces,
                  tr_ref: Traces, summary: dict, plots: bool = True, rerun: bool = False) -> dict:
    outdir = Path(outdir)
    files = {}
    _write_csv(outdir / "runs.csv", rows)
    files["table"] = "runs.csv"
    if _write_parquet(outdir / "runs.parquet", rows):
        files["parquet"] = "runs.parquet"
    else:
        summary.setdefault("notes", []).append("pyarrow is not installed: no runs.parquet (CSV only)")
    _write_csv(outdir / "recommendations.csv", recs)
    (outdir / "recommendations.json").write_text(json.dumps(recs, indent=2, default=float))
    f32 = np.float32
    np.savez_compressed(outdir / "traces.npz", t=np.asarray(tr.t, dtype=f32),
                        acc=np.asarray(tr.acc, dtype=f32), gyro=np.asarray(tr.gyro, dtype=f32),
                        pose=np.asarray(tr.pose, dtype=f32), wheel_z=np.asarray(tr.wheel_z, dtype=f32),
                        tire_f=np.asarray(tr.tire_f, dtype=f32), susp=np.asarray(tr.susp, dtype=f32),
                        acc_baseline=np.asarray(tr_ref.acc, dtype=f32), gyro_baseline=np.asarray(tr_ref.gyro, dtype=f32),
                        run_id=np.array([s.run_id for s in specs]), defect=np.array([s.defect for s in specs]),
                        speed_kmh=np.array([s.speed_kmh for s in specs]),
                        lateral_offset_m=np.array([s.offset_m for s in specs]),
                        vehicle=np.array([s.vehicle for s in specs]),
                        window=np.array([s.window for s in specs]), t_front=np.array([s.t_front for s in specs]))
    files["traces"] = "traces.npz"
    if plots:
        plot_g_vs_speed(outdir / "g_vs_speed.png", rows, recs)
        files["g_vs_speed"] = "g_vs_speed.png"
        for d in list(dict.fromkeys(s.defect for s in specs))[:8]:
            name = "imu_" + "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in d) + ".png"
            plot_crossing(outdir / name, d, specs, tr, tr_ref)
            files.setdefault("imu_plots", []).append(name)
    if rerun:
        msg = write_rerun(outdir / "sweep.rrd", specs, tr)
        summary.setdefault("notes", []).append(msg)
        if msg.startswith("wrote"):
            files["rerun"] = "sweep.rrd"
    summary["files"] = files
    (outdir / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return files


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
    import dataclasses

    return dataclasses.asdict(obj) if dataclasses.is_dataclass(obj) else dict(obj)
