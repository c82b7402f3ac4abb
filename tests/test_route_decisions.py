"""Bypass-or-cross decisions from a vibration sweep (issue "plan", item 6), on a hand-made grid."""
from __future__ import annotations

import json

import numpy as np
import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.grid import GridMap
from roadtwin_core.planning import Vehicle
from roadtwin_core.route_decisions import decide, defects_on_route, load_recommendations


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


def _sweep(tmp_path, rows):
    (tmp_path / "recommendations.json").write_text(json.dumps(rows))
    return tmp_path


ROUTE = np.column_stack([np.linspace(0.0, 38.0, 100), np.zeros(100)])


def test_only_defects_under_a_wheel_are_on_the_route():
    g = _grid()
    assert [g.defect_ids[k] for k in defects_on_route(g, ROUTE, Vehicle())] == ["A", "C"]


def test_cross_when_g_at_recommended_speed_is_low_else_bypass(tmp_path):
    sweep = _sweep(tmp_path, [
        {"defect": "A", "g_at_recommended": 1.6, "recommended_speed_kmh": 10},
        {"defect": "A", "g_at_recommended": 0.7, "recommended_speed_kmh": 20},   # a better line: taken
        {"defect": "B", "g_at_recommended": 0.1, "recommended_speed_kmh": 50},
    ])
    out = {d.defect: d for d in decide(_grid(), ROUTE, Vehicle(), sweep, max_g=1.0)}
    assert set(out) == {"A", "C"}
    assert out["A"].decision == "cross" and out["A"].speed_kmh == 20 and out["A"].g_at_speed == 0.7
    assert out["C"].decision == "bypass" and "no sweep data" in out["C"].reason
    strict = {d.defect: d for d in decide(_grid(), ROUTE, Vehicle(), sweep, max_g=0.5)}
    assert strict["A"].decision == "bypass"


def test_bad_sweep_folder_is_refused(tmp_path):
    with pytest.raises(RoadtwinError, match="no recommendations.json"):
        load_recommendations(tmp_path)
    (tmp_path / "recommendations.json").write_text("{nope")
    with pytest.raises(RoadtwinError, match="not valid JSON"):
        load_recommendations(tmp_path)
