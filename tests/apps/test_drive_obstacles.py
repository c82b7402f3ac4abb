"""Vehicles standing in the lanes (props placed "lane") and ``roadtwin drive``'s routes: ``auto``
keeps the ego body clear of them, a route given by lanes that runs into one is one line.

Clearance checked independently of the code: shapely's distance between the ego body (a W x L
rectangle centred on each route point along its tangent) and the standing car's rectangle, not
the module's arclength spans.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from shapely.geometry import Polygon

from roadtwin_core.apps.drive.obstacles import Obstacle, check_clear, free_stretches, lane_obstacles
from roadtwin_core.apps.drive.route import build_route
from roadtwin_core.errors import RoadtwinError
from roadtwin_core.render.cameras import Lane

BODY = (1.8, 4.5)        # width, length (m)


def _box(cx, cy, yaw=0.0, length=4.5, width=1.8) -> np.ndarray:
    t, n = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
    return np.array([[cx, cy] + a * length / 2 * t + b * width / 2 * n for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def _car(cx, cy, where, yaw=0.0) -> Obstacle:
    return Obstacle(tuple(map(tuple, _box(cx, cy, yaw))), where)


def _min_gap(route, obstacle: Obstacle, step=0.1) -> float:
    """Smallest distance (m) between the body along the route and the obstacle (0: they touch)."""
    s = np.arange(0.0, route.length + step / 2, step)
    p, t = route.at(s)
    yaw = np.arctan2(t[:, 1], t[:, 0])
    other = Polygon(obstacle.corners)
    return min(Polygon(_box(x, y, a, BODY[1], BODY[0])).distance(other) for (x, y), a in zip(p, yaw))


def _straight(lane_id="east", y=0.0, length=300.0):
    return Lane(lane_id, np.column_stack([np.linspace(0, length, 61), np.full(61, y)]))


def test_auto_route_keeps_the_body_clear_of_a_car_standing_in_its_lane():
    lanes = [_straight()]
    car = _car(150.0, 0.55, "/T/Props/LaneVehicles instance 0")
    r = build_route("auto", lanes, [], 120.0, 0.8, 0.1, [car], BODY)
    assert r.length == pytest.approx(120.0)
    assert _min_gap(r, car) > 0.0
    # without knowing about the car, the same request drives into it (the drive this replaces)
    blind = build_route("auto", lanes, [], 250.0, 0.8, 0.1, None, BODY)
    assert _min_gap(blind, car) == 0.0


def test_auto_route_prefers_a_clear_stretch_of_full_length_to_more_defects():
    """Two lanes: one with a defect in the wheel track but a car in the way of any 200 m
    stretch, one clear: the clear lane, at the full length asked for."""
    lanes = [_straight("busy", 0.0, 260.0), _straight("clear", 50.0, 260.0)]
    defect = {"id": "D1", "xy": (60.0, 0.8), "half_width_m": 0.3}
    car = _car(130.0, 0.0, "/T/Props/LaneVehicles instance 0", yaw=0.3)
    r = build_route("auto", lanes, [defect], 200.0, 0.8, 0.1, [car], BODY)
    assert r.lanes == ["clear"] and r.length == pytest.approx(200.0) and _min_gap(r, car) > 0.0
    # no clear stretch of the full length anywhere: the longest clear one, said in the source
    r = build_route("auto", lanes[:1], [defect], 200.0, 0.8, 0.1, [car], BODY)
    assert r.length < 200.0 and "vehicles stand in the lanes" in r.source and _min_gap(r, car) > 0.0


def test_cars_in_the_next_lane_or_beyond_the_route_do_not_block_it():
    lanes = [_straight()]
    # parked at the right edge of the lane on the left (3.5 m wide): 3.5 - 0.55 - 0.9 - 0.9 = 1.15 m clear
    beside = _car(100.0, 3.5 - 0.55, "next lane")
    ahead = _car(320.0, 0.0, "past the end")                  # on the lane's line, 20 m past its end
    r = build_route("lane:east", lanes, [], None, 0.8, 0.1)
    check_clear(r, [beside, ahead], *BODY)
    assert _min_gap(r, beside) == pytest.approx(1.15) and _min_gap(r, ahead) > 0


def test_a_lane_route_into_a_standing_car_is_one_line_naming_it():
    r = build_route("lane:east", [_straight()], [], None, 0.8, 0.1)
    car = _car(180.0, -0.2, "/T/Props/LaneVehicles instance 3", yaw=np.pi)
    with pytest.raises(RoadtwinError) as e:
        check_clear(r, [car], *BODY)
    msg = str(e.value)
    assert "\n" not in msg and "/T/Props/LaneVehicles instance 3" in msg and "x = 180.00" in msg


def test_free_stretches_leave_out_every_blocked_span():
    spans = [(-3.0, 4.0, None), (50.0, 60.0, None), (55.0, 70.0, None), (95.0, 130.0, None)]
    assert free_stretches(100.0, spans) == [(4.0, 50.0), (70.0, 95.0)]
    assert free_stretches(100.0, []) == [(0.0, 100.0)]


def test_only_instancers_placed_in_the_lanes_are_obstacles():
    def inst(path, place, xy):
        return SimpleNamespace(path=path, place=place, positions=np.array([[*xy, 0.0]]), corners=_box(*xy)[None])

    town = SimpleNamespace(instances=[inst("/T/Props/LaneVehicles", "lane", (1, 2)),
                                      inst("/T/Props/Vehicles", "roadside", (3, 4)),
                                      inst("/T/Props/MapVehicles", "lane", (5, 6))])
    assert [o.where for o in lane_obstacles(town)] == ["/T/Props/LaneVehicles instance 0",
                                                        "/T/Props/MapVehicles instance 0"]
