"""Bypass-or-cross decisions from a vibration sweep (issue "plan", item 6), on a hand-made grid."""
from __future__ import annotations

import json

import numpy as np
import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.planning.grid import GridMap
from roadtwin_core.apps.plan import decide, defects_on_route, load_recommendations, sweep_vehicle_name
from roadtwin_core.vehicle import DEFAULT_CAR, paper_car
from roadtwin_core.apps.sweep.run import dataclass_dict

CAR = paper_car()   # 2.0 m track: wheels at y = +-1 m on the route below


def _grid():
    """A 40 m x 8 m road, 0.2 m cells, route along y = 0 (wheels at y = +-1 m): defect A under the
    left wheels at x = 10, B between the wheels (straddled) at x = 20, C under the right wheels at x = 30."""
    res = 0.2
    nx, ny = 200, 40
    origin = (0.0, -4.0)
    idx = np.full((ny, nx), -1, dtype=np.int32)

    def square(cx, cy, k):
        ix0, iy0 = int((cx - 0.3 - origin[0]) / res), int((cy - 0.3 - origin[1]) / res)
        idx[iy0:iy0 + 3, ix0:ix0 + 3] = k

    square(10.0, 1.0, 0)
    square(20.0, 0.0, 1)
    square(30.0, -1.0, 2)
    return GridMap.build(origin, res, np.ones((ny, nx), bool), defect=idx >= 0, defect_index=idx,
                         defect_ids=["A", "B", "C"], defect_types=["pothole", "pothole", "bump"])


def _sweep(tmp_path, rows, cars=None):
    """A sweep folder as ``roadtwin sweep`` writes it: its rows and the cars it drove."""
    cars = {CAR.name: CAR} if cars is None else cars
    (tmp_path / "recommendations.json").write_text(json.dumps(rows))
    (tmp_path / "summary.json").write_text(json.dumps({"vehicles": {n: dataclass_dict(c) for n, c in cars.items()}}))
    return tmp_path


ROUTE = np.column_stack([np.linspace(0.0, 38.0, 100), np.zeros(100)])


def test_only_defects_under_a_wheel_are_on_the_route():
    g = _grid()
    assert [g.defect_ids[k] for k in defects_on_route(g, ROUTE, CAR.footprint())] == ["A", "C"]


def test_cross_when_g_at_recommended_speed_is_low_else_bypass(tmp_path):
    sweep = _sweep(tmp_path, [
        {"defect": "A", "g_at_recommended": 1.6, "recommended_speed_kmh": 10},
        {"defect": "A", "g_at_recommended": 0.7, "recommended_speed_kmh": 20},   # a better line: taken
        {"defect": "B", "g_at_recommended": 0.1, "recommended_speed_kmh": 50},
    ])
    out = {d.defect: d for d in decide(_grid(), ROUTE, CAR, sweep, max_g=1.0)}
    assert set(out) == {"A", "C"}
    assert out["A"].decision == "cross" and out["A"].speed_kmh == 20 and out["A"].g_at_speed == 0.7
    assert out["C"].decision == "bypass" and "no sweep data" in out["C"].reason
    strict = {d.defect: d for d in decide(_grid(), ROUTE, CAR, sweep, max_g=0.5)}
    assert strict["A"].decision == "bypass"


def test_bad_sweep_folder_is_refused(tmp_path):
    with pytest.raises(RoadtwinError, match="no recommendations.json"):
        load_recommendations(tmp_path)
    (tmp_path / "recommendations.json").write_text("{nope")
    with pytest.raises(RoadtwinError, match="not valid JSON"):
        load_recommendations(tmp_path)


def test_decisions_use_the_car_being_planned_for(tmp_path):
    """plan --sweep: vibration must come from the car the route is planned for (issue 13). A sweep
    that drove only another car (the default 1.55 m track sedan) is refused; one that drove
    several uses the rows of the planned car only."""
    rows = [{"defect": "A", "vehicle": "default_car", "g_at_recommended": 0.2, "recommended_speed_kmh": 40},
            {"defect": "A", "vehicle": CAR.name, "g_at_recommended": 1.5, "recommended_speed_kmh": 10}]
    (tmp_path / "other").mkdir()
    (tmp_path / "both").mkdir()
    other = _sweep(tmp_path / "other", rows[:1], {"default_car": DEFAULT_CAR})
    with pytest.raises(RoadtwinError, match="track 1.55 m, wheelbase 2.7 m.*paper_car .track 2 m, wheelbase 3 m"):
        decide(_grid(), ROUTE, CAR, other)
    both = _sweep(tmp_path / "both", rows, {"default_car": DEFAULT_CAR, "renamed": CAR})
    assert sweep_vehicle_name(both, CAR) == "renamed"   # same parameters, any name
    rows[1]["vehicle"] = "renamed"
    (both / "recommendations.json").write_text(json.dumps(rows))
    out = {d.defect: d for d in decide(_grid(), ROUTE, CAR, both, max_g=1.0)}
    assert out["A"].decision == "bypass" and out["A"].g_at_speed == 1.5   # not the sedan's 0.2
    (both / "summary.json").unlink()
    with pytest.raises(RoadtwinError, match="no summary.json"):
        decide(_grid(), ROUTE, CAR, both)
