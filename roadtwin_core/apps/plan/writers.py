"""plan's file outputs: path.csv, metrics.json, comparison.csv."""
from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any, Iterable

from ...planning import PlanFailure, PlanResult, wrap_angle


def write_path_csv(path: Path, result: PlanResult) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["x", "y", "z", "yaw"])
        for (x, y, yaw), z in zip(result.poses, result.z):
            w.writerow([f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", f"{float(wrap_angle(yaw)):.6f}"])
    return path


def write_metrics_json(path: Path, result: PlanResult, extra: dict[str, Any] | None = None) -> Path:
    data = result.as_dict()
    data.update(extra or {})
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    return path


COMPARISON_COLUMNS = ("planner", "collision", "status", "length_m", "reference_length_m", "deviation_pct",
                      "smoothness_rad_per_m", "mean_clearance_m", "min_clearance_m", "wheel_in_defect",
                      "off_road", "time_s")


def comparison_rows(results: Iterable[PlanResult | PlanFailure]) -> list[dict[str, Any]]:
    rows = []
    for r in results:
        if isinstance(r, PlanFailure):
            rows.append({"planner": r.planner, "collision": r.collision, "status": f"failed: {r.reason}",
                         "time_s": round(r.time_s, 3)})
            continue
        m = r.metrics
        rows.append({"planner": r.planner, "collision": r.collision, "status": "ok",
                     "length_m": round(m.length_m, 3), "reference_length_m": round(m.reference_length_m, 3),
                     "deviation_pct": round(m.deviation_pct, 3), "smoothness_rad_per_m": round(m.smoothness_rad_per_m, 4),
                     "mean_clearance_m": round(m.mean_clearance_m, 3), "min_clearance_m": round(m.min_clearance_m, 3),
                     "wheel_in_defect": m.wheel_in_defect, "off_road": m.off_road, "time_s": round(r.time_s, 3)})
    return rows


def write_comparison_csv(path: Path, results: Iterable[PlanResult | PlanFailure]) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COMPARISON_COLUMNS)
        w.writeheader()
        for row in comparison_rows(results):
            w.writerow(row)
    return path

