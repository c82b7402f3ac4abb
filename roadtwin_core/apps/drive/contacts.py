"""Wheel-defect contact events: which wheel, which defect, when it entered and left.

Each tire's contact patch (``tire_width_m`` x ``tire_contact_length_m``, sampled 3 x 3 under the
wheel centre, following the body's yaw) is tested against every defect's footprint (the union
of its baked triangles in XY, shapely) at every physics sample; an event runs from the first
sample with any patch point inside to the last (gaps under 30 ms closed).
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import shapely
from shapely.ops import unary_union

__all__ = ["WHEELS", "defect_footprints", "contact_events", "write_events"]

WHEELS = ("FL", "FR", "RL", "RR")


def defect_footprints(town, ids=None) -> dict:
    """{defect id: shapely geometry} of a town's defects (their baked triangles, unioned); only
    those in ``ids`` when given."""
    out = {}
    for d in town.defects:
        if ids is not None and d.id not in ids:
            continue
        v, f = d.mesh()
        if len(f) == 0:
            continue
        tri = shapely.polygons(v[np.asarray(f)][:, :, :2])
        geom = unary_union([g for g in tri if g.area > 1e-10]).buffer(0)
        shapely.prepare(geom)
        out[d.id] = geom
    return out


def contact_events(traj, vehicle, footprints: dict, defect_types: dict, merge_gap_s: float = 0.03) -> list[dict]:
    if not footprints:
        return []
    c = [vehicle.corner(i) for i in range(4)]
    du = np.array([-0.5, 0.0, 0.5]) * vehicle.tire_contact_length_m
    dv = np.array([-0.5, 0.0, 0.5]) * vehicle.tire_width_m
    yaw = traj.pose[:, 5]
    cy, sy = np.cos(yaw), np.sin(yaw)
    bounds = {k: g.bounds for k, g in footprints.items()}
    events = []
    dt = float(np.median(np.diff(traj.t))) if len(traj.t) > 1 else 1e-3
    for w in range(4):
        inside = {k: np.zeros(len(traj.t), bool) for k in footprints}
        for a in du:
            for b in dv:
                x = c[w]["x"] + a
                y = c[w]["y"] + b
                px = traj.pose[:, 0] + cy * x - sy * y
                py = traj.pose[:, 1] + sy * x + cy * y
                for k, g in footprints.items():
                    x0, y0, x1, y1 = bounds[k]
                    near = (px >= x0) & (px <= x1) & (py >= y0) & (py <= y1)
                    if near.any():
                        idx = np.flatnonzero(near)
                        inside[k][idx] |= shapely.contains_xy(g, px[idx], py[idx])
        for k, m in inside.items():
            if not m.any():
                continue
            idx = np.flatnonzero(m)
            splits = np.flatnonzero(np.diff(traj.t[idx]) > merge_gap_s + dt) + 1
            for run in np.split(idx, splits):
                i0, i1 = int(run[0]), int(run[-1])
                events.append({"wheel": WHEELS[w], "defect": k, "defect_type": defect_types.get(k, ""),
                               "t_entry_s": float(traj.t[i0]), "t_exit_s": float(traj.t[i1]),
                               "s_entry_m": float(traj.s[i0]), "speed_kmh": float(traj.speed[i0] * 3.6),
                               "tire_force_min_n": float(np.nanmin(traj.tire_f[i0:i1 + 1, w])),
                               "tire_force_max_n": float(np.nanmax(traj.tire_f[i0:i1 + 1, w]))})
    events.sort(key=lambda e: (e["t_entry_s"], e["wheel"]))
    return events


def write_events(folder: Path, events: list[dict]) -> None:
    (folder / "contacts.json").write_text(json.dumps(events, indent=2))
    keys = ["wheel", "defect", "defect_type", "t_entry_s", "t_exit_s", "s_entry_m", "speed_kmh", "tire_force_min_n",
            "tire_force_max_n"]
    with open(folder / "contacts.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(events)
