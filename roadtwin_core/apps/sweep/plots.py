"""The sweep's figures: g vs speed per defect (star: the recommended speed) and the IMU of one
crossing at a few speeds (the paper's figure). matplotlib is imported when a plot is drawn."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...vehicle import Traces
from .matrix import RunSpec

__all__ = ["plot_crossing", "plot_g_vs_speed"]


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

