"""Recommended speeds from the sweep's table.

Recommended speed per (defect, offset, vehicle): the fastest swept speed whose g is within 25 % of
the least g of the sweep (so a deep pothole gets "slow down", a small one whose g falls again at
speed may get "keep going"). Also reported: the fastest swept speed whose crossing stays at most
"a little uncomfortable" (aw < 0.561 m/s^2, see ``metrics.py``), or none, and where g peaks.
"""
from __future__ import annotations

import numpy as np

from ...vehicle.metrics import BAND_EDGES

__all__ = ["recommend"]


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

