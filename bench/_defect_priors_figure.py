"""The figure of bench/defect_priors.py: what the real labels hold beside what the twin drew
(the fitted priors and the parametric types' own ranges), and how far ahead each is seen."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from roadtwin_core import get_plugin_manager
from roadtwin_core.render.view_sampler import DEFECT_DISTANCE_M as DEFAULT_AIM_M   # render --views defects:SHARE


def own_draws(defect_type: str, key: str, n: int = 5000) -> np.ndarray:
    """``key`` of ``n`` parameter draws of the registered type (what compose draws without priors)."""
    dtype = get_plugin_manager().get("defect_types", defect_type)
    rng = np.random.default_rng(0)
    return np.array([getattr(dtype.sample_params(rng), key) for _ in range(n)])


def plot(m: dict, fits: dict, out: Path, aim_m: tuple[float, float] = (2.5, 8.0)) -> Path:
    """Three panels: pothole radius, crack network extent (real histogram, the fitted lognormal
    drawn, the registered type's own draws), distance ahead (real potholes and cracks, the
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
        ax.hist(own_draws(name, key), bins=bins, density=True, histtype="step", lw=1.5, ls="--", color="grey",
                label="the type's own draws (without priors)")
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
