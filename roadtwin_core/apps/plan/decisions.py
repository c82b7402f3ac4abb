"""Bypass or cross: decide, for each defect on the route, from a vibration sweep.

Beyond the paper (issue "plan", item 6): a defect that the undisturbed route would put a wheel
into is either *bypassed* (the wheel-level planner's path avoids it) or *crossed* at the speed
the sweep recommends for it. Crossing is chosen when the sweep's vibration degree g at the
recommended speed is at most ``max_g`` (default 1.0: below the g the sweep reports for a
large deep pothole at town speeds, above what a small shallow one gives at its best speed);
otherwise the defect is bypassed. The sweep's rows for a defect may cover several lateral
offsets; the best (lowest g at the recommended speed) is taken, since a driver who crosses
picks the line. A defect the sweep does not cover is bypassed ("no sweep data").

The sweep must have driven the car being planned for (issue 13: one vehicle): the sweep's
``summary.json`` records every vehicle it drove, and :func:`sweep_vehicle_name` refuses a sweep
none of whose cars equals the plan's vehicle; only that car's rows are used.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from ...errors import RoadtwinError
from ...planning import Footprint, resample_by_length, transform
from ...vehicle import VehicleParams, vehicle_from_dict


@dataclass
class Decision:
    defect: str
    defect_type: str
    decision: str               # "cross" or "bypass"
    speed_kmh: float | None     # crossing speed when crossing
    g_at_speed: float | None    # sweep's g at that speed
    reason: str


def load_recommendations(sweep_dir: str | Path, vehicle: str | None = None) -> dict[str, dict]:
    """``recommendations.json`` of ``roadtwin sweep``: the best row per defect (of the sweep's
    car named ``vehicle`` when given)."""
    path = Path(sweep_dir) / "recommendations.json"
    if not path.exists():
        raise RoadtwinError(f"{sweep_dir}: no recommendations.json (give the output folder of roadtwin sweep)")
    try:
        rows = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise RoadtwinError(f"{path}: not valid JSON ({exc.msg})") from None
    best: dict[str, dict] = {}
    for r in rows:
        if not isinstance(r, dict) or "defect" not in r or "g_at_recommended" not in r:
            raise RoadtwinError(f"{path}: rows need 'defect' and 'g_at_recommended'")
        if vehicle is not None and r.get("vehicle", vehicle) != vehicle:
            continue
        if r["defect"] not in best or r["g_at_recommended"] < best[r["defect"]]["g_at_recommended"]:
            best[r["defect"]] = r
    return best


def _same_car(a: VehicleParams, b: VehicleParams) -> bool:
    return all(math.isclose(getattr(a, f.name), getattr(b, f.name), rel_tol=1e-9, abs_tol=1e-12)
               for f in fields(VehicleParams) if f.name != "name")


def sweep_vehicle_name(sweep_dir: str | Path, vehicle: VehicleParams) -> str:
    """The name under which the sweep in ``sweep_dir`` drove ``vehicle`` (every parameter equal,
    the name aside); a RoadtwinError when it drove other cars only, or does not say."""
    path = Path(sweep_dir) / "summary.json"
    if not path.is_file():
        raise RoadtwinError(f"{sweep_dir}: no summary.json, so the car the sweep drove is unknown "
                            f"(give the output folder of roadtwin sweep)")
    try:
        cars = json.loads(path.read_text())["vehicles"]
        cars = {str(n): vehicle_from_dict(dict(d), f"{path}: vehicle {n}") for n, d in cars.items()}
    except (ValueError, KeyError, TypeError, AttributeError):
        raise RoadtwinError(f"{path}: no readable 'vehicles' table (give the output folder of roadtwin sweep)") from None
    for name, car in cars.items():
        if isinstance(car, VehicleParams) and _same_car(car, vehicle):
            return name
    drove = ", ".join(f"{n} (track {c.track_rear_m:g} m, wheelbase {c.wheelbase_m:g} m)"
                      for n, c in cars.items() if isinstance(c, VehicleParams)) or "no full car"
    raise RoadtwinError(f"{sweep_dir}: the sweep drove {drove}, not the car being planned for, {vehicle.name} "
                        f"(track {vehicle.track_rear_m:g} m, wheelbase {vehicle.wheelbase_m:g} m): give plan and "
                        f"sweep the same --vehicle file")


def defects_on_route(grid, reference: np.ndarray, footprint: Footprint, step: float = 0.1) -> list[int]:
    """Indices (into ``grid.defect_ids``) of defects a wheel contact centre passes over when the
    vehicle follows the reference route, in the order they are met."""
    poses = resample_by_length(np.column_stack([reference, _headings(reference)]), step)
    wheels = transform(poses, footprint.wheel_offsets()).reshape(-1, 2)
    ix, iy = grid.world_to_cell(wheels)
    ny, nx = grid.defect_index.shape
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    hit = np.full(len(wheels), -1)
    hit[inside] = grid.defect_index[iy[inside], ix[inside]]
    order = []
    for k in hit:
        if k >= 0 and k not in order:
            order.append(int(k))
    return order


def _headings(xy: np.ndarray) -> np.ndarray:
    d = np.diff(xy, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.concatenate([h, h[-1:]])


def decide(grid, reference: np.ndarray, vehicle: VehicleParams, sweep_dir: str | Path,
           max_g: float = 1.0) -> list[Decision]:
    """Bypass or cross for each defect under a wheel of ``vehicle`` on the reference route, from
    the sweep's rows for that same car (refused when the sweep drove another car)."""
    recs = load_recommendations(sweep_dir, sweep_vehicle_name(sweep_dir, vehicle))
    out = []
    for k in defects_on_route(grid, reference, vehicle.footprint()):
        did = grid.defect_ids[k]
        dtype = grid.defect_types[k] if k < len(grid.defect_types) else ""
        r = recs.get(did)
        if r is None:
            out.append(Decision(did, dtype, "bypass", None, None, "no sweep data for this defect"))
        elif r["g_at_recommended"] <= max_g:
            out.append(Decision(did, dtype, "cross", float(r["recommended_speed_kmh"]), float(r["g_at_recommended"]),
                                f"g {r['g_at_recommended']:.2f} <= {max_g:g} at {r['recommended_speed_kmh']:g} km/h"))
        else:
            out.append(Decision(did, dtype, "bypass", float(r["recommended_speed_kmh"]), float(r["g_at_recommended"]),
                                f"g {r['g_at_recommended']:.2f} > {max_g:g} even at the best speed "
                                f"({r['recommended_speed_kmh']:g} km/h)"))
    return out


def write_decisions(outdir: Path, decisions: list[Decision]) -> None:
    rows = [asdict(d) for d in decisions]
    (outdir / "decisions.json").write_text(json.dumps(rows, indent=2) + "\n")
    with open(outdir / "decisions.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(Decision.__dataclass_fields__))
        w.writeheader()
        w.writerows(rows)
