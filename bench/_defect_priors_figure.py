"""The figure of bench/defect_priors.py: what the real labels hold beside what the twin drew
(the fitted priors and the parametric types' own ranges), and how far ahead each is seen."""
from __future__ import annotations

from pathlib import Path

import numpy as np

# the parametric types' own draws (plugins/roadtwin_defects: pothole.py, crack.py) and the
# view sampler's default aim (render --views defects:SHARE)
OWN_RANGE_M = {"radius_m": (0.10, 0.50), "extent_m": (0.5, 2.0)}
DEFAULT_AIM_M = (5.0, 25.0)


def plot(m: dict, fits: dict, out: Path, aim_m: tuple[float, float] = (2.5, 8.0)) -> Path:
    """Three panels: pothole radius, crack network extent (real histogram, the fitted lognormal
    drawn, the type's own uniform range shaded), distance ahead (real potholes and cracks, the
    default and the matched aim ranges shaded). ``fits``: {(class, key): (median, sigma, lo, hi)}."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    rng = np.random.default_rng(0)
    for ax, (name, key, label) in zip(axes[:2], (("pothole", "radius_m", "pothole equivalent radius (m)"),
                                                  ("crack", "extent_m", "crack network extent (m)"))):
        real = m[name][key]
        bins = np.logspace(np.log10(max(real.min(), 0.02)), np.log10(real.max()), 40)
        med, sig, lo, hi = fits[(name, key)]
        drawn = med * np.exp(sig * rng.standard_normal(200000))
        drawn = drawn[(drawn >= lo) & (drawn <= hi)][:20000]          # truncated, as the priors draw
        ax.hist(real, bins=bins, density=True, alpha=0.55, color="tab:blue", label=f"real train labels ({len(real)})")
        ax.hist(drawn, bins=bins, density=True, histtype="step", lw=2, color="tab:red",
                label=f"--defect-priors: lognormal {med:.2f} m, sigma {sig:.2f}, truncated")
        ax.axvspan(*OWN_RANGE_M[key], color="grey", alpha=0.25, label="the type's own draw (uniform)")
        ax.set(xscale="log", xlabel=label, ylabel="density")
        ax.legend(fontsize=8)
    ax = axes[2]
    bins = np.linspace(0, 26, 53)
    for name, color in (("pothole", "tab:blue"), ("crack", "tab:orange")):
        d = m[name]["distance_m"]
        ax.hist(d, bins=bins, density=True, alpha=0.5, color=color, label=f"real {name}s: median {np.median(d):.1f} m")
    ax.axvspan(*DEFAULT_AIM_M, color="grey", alpha=0.2, label="aim, default (5-25 m)")
    ax.axvspan(*aim_m, color="tab:green", alpha=0.2, label=f"aim, matched ({aim_m[0]:g}-{aim_m[1]:g} m)")
    ax.set(xlabel="distance ahead of the camera (m)", ylabel="density")
    ax.legend(fontsize=8)
    fig.suptitle("road_defects_br train labels back-projected through the survey rig: the real defects' size and "
                 "distance beside what the twin drew", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
