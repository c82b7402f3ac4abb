"""One table row per vehicle run: the crossing metrics of the run against its twin.

Crossing metrics (see ``metrics.py``): ``g`` = peak of g(t) over the window. Why the peak: a
pothole crossing is a transient shock, and ISO 2631-1 (6.3) warns that the basic RMS method can
understate such events and adds peak-type measures (MTVV, VDV); the vibration degree has no
standard weighting, so its maximum over the crossing is used. Each IMU sample is already a mean
over its interval (2 ms at 500 Hz), so the peak does not depend on the time step. ``g_rms`` =
sqrt(integral of g^2 over the window / T_ref) with T_ref the window length of the slowest speed
of that defect (g' is 0 outside a run's own window), i.e. the energy of g, comparable across
speeds. ``aw``, ``rms_az``, ``peak_az`` are over the run's own window.
"""
from __future__ import annotations

import math

import numpy as np

from ...vehicle import Traces, window_metrics
from .matrix import KMH, RunSpec

__all__ = ["compute_rows"]


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

