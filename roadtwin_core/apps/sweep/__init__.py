"""``roadtwin sweep``: vibration sweeps, speeds x defects x lateral offsets x vehicle parameter
sets, on any physics backend, with a tidy table, IMU traces, plots and a recommended speed per
defect (the paper's speed-control study).

One concern per module: ``matrix`` (which runs, their timing, simulating them and their twins),
``rows`` (crossing metrics per run), ``recommend`` (recommended speeds), ``plots`` (figures),
``outputs`` (files), ``run`` (``run_sweep`` ties them together). The vehicle, its runs and traces
and the ride metrics are the framework's (``roadtwin_core.vehicle``).
"""
from .matrix import KMH, RunSpec, SweepConfig, build_matrix, parse_offsets, parse_speeds, simulate_specs
from .outputs import write_outputs, write_rerun
from .plots import plot_crossing, plot_g_vs_speed
from .recommend import recommend
from .rows import compute_rows
from .run import run_sweep

__all__ = ["KMH", "RunSpec", "SweepConfig", "build_matrix", "compute_rows", "parse_offsets", "parse_speeds",
           "plot_crossing", "plot_g_vs_speed", "recommend", "run_sweep", "simulate_specs", "write_outputs",
           "write_rerun"]
