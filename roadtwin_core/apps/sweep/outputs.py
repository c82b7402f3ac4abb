"""The sweep's output files.

Outputs (``write_outputs``): ``runs.csv`` (+ ``runs.parquet`` when pyarrow is installed), one row
per vehicle run with backend, defect, type, speed (km/h and m/s), lateral offset, vehicle, the
crossing metrics g, g_rms, aw, comfort band, rms_az, peak_az, the whole-run ones (run_*), the
window and whether it was clipped, and whether the vehicle left the road; ``recommendations.csv`` / ``.json``; ``traces.npz`` (IMU of
every run and its twin); ``g_vs_speed.png``; ``imu_<defect>.png`` (wx, wy, az of one crossing at a
few speeds, the paper's figure); ``summary.json``; ``sweep.rrd`` with ``rerun=True`` when
rerun-sdk is installed.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from ...vehicle import Traces
from .matrix import RunSpec
from .plots import plot_crossing, plot_g_vs_speed

__all__ = ["write_outputs", "write_rerun"]


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

