"""What a sweep runs on, from the command's options: the simulation parameters (tire sampling) and
the scenario (a composed town's defects, or a straight ISO 8608 test road)."""
from __future__ import annotations

import re
from pathlib import Path

from ...errors import RoadtwinError
from ...vehicle import Scenario, SimParams, load_town_scenario, straight_road_scenario

__all__ = ["load_scenario", "parse_tire", "sim_params"]


def parse_tire(spec: str) -> tuple[int, int, int]:
    """``SLICESxARC_RAYS[+BISECTION_ROUNDS]`` -> (slices, arc rays, rounds)."""
    m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*(?:\+\s*(\d+))?\s*", str(spec))
    if not m:
        raise RoadtwinError(f"sweep: --tire {spec!r}: expected SLICESxARC_RAYS[+ROUNDS], e.g. 3x7+2")
    return int(m.group(1)), int(m.group(2)), int(m.group(3) or 0)


def sim_params(dt: float, imu_rate: float, device: str, tire: str) -> SimParams:
    """Checked simulation parameters of a sweep."""
    nl, na, refine = parse_tire(tire)
    return SimParams(dt_s=dt, imu_rate_hz=imu_rate, device=device, tire_slices=nl, tire_arc_samples=na,
                     tire_refine=refine).check("sweep")


def load_scenario(stage: Path | None, surface: str | None, length: float, seed: int,
                  defects: str | None) -> Scenario:
    """The defects to cross: ``defects`` (comma separated ids, default all) of a town ``stage``, or
    of a straight test road ``surface`` (``iso8608:CLASS`` or ``flat``) ``length`` m long."""
    if seed < 0:
        raise RoadtwinError(f"sweep: seed must be >= 0, got {seed}")
    ids = [d.strip() for d in defects.split(",") if d.strip()] if defects else None
    if defects is not None and not ids:
        raise RoadtwinError(f"sweep: --defects {defects!r} names no defect")
    if surface is not None:
        scenario = straight_road_scenario(length, None if surface.strip().lower() == "flat" else surface, seed)
        return scenario.select(ids)
    if not stage.exists():
        raise RoadtwinError(f"{stage}: no such file")
    return load_town_scenario(stage, ids)
