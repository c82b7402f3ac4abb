"""Top-down preview PNG of a composed town: road elevation shaded, defects by relative depth."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def write_preview(path: Path, layout, merged, owners, placements, dpi: int = 110) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    fig, axes = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [1.6, 1]})
    ax = axes[0]
    road_tris, road_z = [], []
    for m in merged:
        road = m.face_owner == -1
        road_tris.append(m.vertices[m.faces[road]][:, :, :2])
        road_z.append(m.vertices[m.faces[road]][:, :, 2].mean(axis=1))
    tris = np.concatenate(road_tris)
    z = np.concatenate(road_z)
    pc = PolyCollection(tris, array=z, cmap="terrain", edgecolors="none")
    ax.add_collection(pc)
    fig.colorbar(pc, ax=ax, label="road elevation (m)", shrink=0.8)
    for p in placements:
        fp = p.world_footprint()
        ax.fill(fp[:, 0], fp[:, 1], color="crimson", lw=0)
    ax.autoscale()
    ax.set_aspect("equal")
    ax.set_title(f"{layout.name}: {len(layout.segments)} segments, {len(placements)} defects")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")

    # Zoom on the busiest defect neighbourhood, heights relative to the local road.
    ax = axes[1]
    if placements:
        centers = np.array([[p.x, p.y] for p in placements])
        d = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
        c = centers[np.argmax((d < 4.0).sum(axis=1))]
        polys, vals, road_pts = [], [], []
        for m in merged:
            tri = m.vertices[m.faces]
            inside = (np.abs(tri[:, :, 0].mean(1) - c[0]) < 4) & (np.abs(tri[:, :, 1].mean(1) - c[1]) < 4)
            if not inside.any():
                continue
            polys.append(tri[inside][:, :, :2])
            vals.append(tri[inside][:, :, 2].mean(1))
            road_pts.append(m.vertices[np.unique(m.faces[inside & (m.face_owner == -1)])])
        if polys:
            # Heights relative to a plane fitted to the road around: terrain slope removed.
            rp = np.concatenate(road_pts)
            coef = np.linalg.lstsq(np.column_stack([np.ones(len(rp)), rp[:, 0], rp[:, 1]]), rp[:, 2], rcond=None)[0]
            vals = [v - (coef[0] + coef[1] * p[:, :, 0].mean(1) + coef[2] * p[:, :, 1].mean(1))
                    for v, p in zip(vals, polys)]
        if polys:
            vals_all = np.concatenate(vals)
            lim = max(float(np.abs(vals_all).max()), 1e-3)
            pc = PolyCollection(np.concatenate(polys), array=vals_all, cmap="RdBu", clim=(-lim, lim),
                                edgecolors="k", linewidths=0.05)
            ax.add_collection(pc)
            fig.colorbar(pc, ax=ax, label="height relative to local road (m)", shrink=0.8)
        ax.set_xlim(c[0] - 4, c[0] + 4)
        ax.set_ylim(c[1] - 4, c[1] + 4)
        ax.set_aspect("equal")
        ax.set_title("merged mesh around the densest defects")
    else:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
