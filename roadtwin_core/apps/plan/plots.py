"""plan's figures: the grid, defects by depth, each path with wheel tracks and body outlines."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ...planning.grid import GridMap
from ...planning import Footprint, PlanResult, resample_by_length

COLOURS = {"astar": "tab:blue", "rrtstar": "tab:orange", "lattice": "tab:green", "hybrid_astar": "tab:purple"}


def _draw_grid(ax, grid: GridMap) -> None:
    import matplotlib.colors as mcolors

    img = np.where(grid.drivable, 0.85, 1.0)
    ax.imshow(img, origin="lower", extent=grid.extent, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    depth = np.ma.masked_where(~grid.defect, grid.depth * 100)
    vmax = max(1.0, float(depth.max()) if grid.defect.any() else 1.0)
    im = ax.imshow(depth, origin="lower", extent=grid.extent, cmap="Reds",
                   norm=mcolors.Normalize(0, vmax), interpolation="nearest")
    if grid.defect.any():  # outline the defects: small ones are only a few cells
        x0, x1, y0, y1 = grid.extent
        ny, nx = grid.shape
        xs = np.linspace(x0 + grid.resolution / 2, x1 - grid.resolution / 2, nx)
        ys = np.linspace(y0 + grid.resolution / 2, y1 - grid.resolution / 2, ny)
        ax.contour(xs, ys, grid.defect.astype(float), levels=[0.5], colors="darkred", linewidths=0.8)
    return im


def _draw_result(ax, result: PlanResult, vehicle: Footprint, colour: str, label: str, tracks: bool = True) -> None:
    p = result.poses
    ax.plot(p[:, 0], p[:, 1], "-", color=colour, lw=1.6, label=label, zorder=4)
    if tracks:
        travel = resample_by_length(p, 0.1)
        w = vehicle.wheel_centres(travel)
        for k in range(4):
            ax.plot(w[:, k, 0], w[:, k, 1], ":", color=colour, lw=0.8, zorder=3)
        s = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(travel[:, :2], axis=0).T))])
        for target in np.arange(0, s[-1] + 1e-9, 6.0):
            pose = travel[int(np.searchsorted(s, target).clip(0, len(travel) - 1))]
            c = vehicle.outline(pose)
            ax.fill(c[:, 0], c[:, 1], fill=False, ec=colour, lw=0.5, alpha=0.6, zorder=3)


def write_plot(path: Path, grid: GridMap, results: Sequence[PlanResult], vehicle: Footprint,
               title: str = "") -> Path:
    """Grid, defects (by depth), each path with its wheel tracks and a body outline every 6 m.
    One result: one panel; several: one panel per result, stacked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x0, x1, y0, y1 = grid.extent
    if results:  # zoom to the paths (and their wheels) plus a margin, within the map
        pts = np.concatenate([np.concatenate([r.poses[:, :2], vehicle.wheel_centres(r.poses).reshape(-1, 2)])
                              for r in results])
        lo, hi = pts.min(axis=0) - 8.0, pts.max(axis=0) + 8.0
        x0, x1, y0, y1 = max(x0, lo[0]), min(x1, hi[0]), max(y0, lo[1]), min(y1, hi[1])
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    n = max(1, len(results))
    width = 13.0
    panel_h = float(np.clip(width * aspect, 1.6, 9.0)) + 0.7
    fig, axes = plt.subplots(n, 1, figsize=(width, panel_h * n + 0.3), squeeze=False)
    im = None
    for ax, r in zip(axes[:, 0], results or [None]):
        im = _draw_grid(ax, grid)
        if r is not None:
            colour = COLOURS.get(r.planner, "tab:cyan")
            _draw_result(ax, r, vehicle, colour, r.planner)
            ax.plot(*r.start[:2], "o", color="k", ms=4, zorder=5)
            ax.plot(*r.goal[:2], "*", color="k", ms=8, zorder=5)
            m = r.metrics
            ax.set_title(f"{r.planner} ({r.collision}-level): length {m.length_m:.2f} m, deviation "
                         f"{m.deviation_pct:.2f} %, smoothness {m.smoothness_rad_per_m:.3f} rad/m, clearance "
                         f"{m.mean_clearance_m:.2f} m (min {m.min_clearance_m:.2f})"
                         + (", WHEEL IN DEFECT" if m.wheel_in_defect else ""), fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    if title:
        fig.suptitle(title, fontsize=10)
    if im is not None and grid.defect.any():
        fig.colorbar(im, ax=axes[:, 0].tolist(), label="defect depth (cm)", shrink=0.8, pad=0.01)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path

