"""View sampler and ego-lane labels: shares, jitter bounds, determinism, lane chaining, and the
ego-lane mask against closed-form geometry. Each check recomputes what it asserts with plain
geometry from the returned poses, never with the sampler's own helpers."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from roadtwin_core.errors import RoadtwinError
from roadtwin_core.render.cameras import Camera, Intrinsics, Lane, look_from
from roadtwin_core.render.ego_lane import ego_lane_mask
from roadtwin_core.render.view_sampler import (DefectTargets, Jitter, ViewRig, chain_lanes, sample_views,
                                               share_with_targets)

STAGES = Path(__file__).resolve().parents[2] / "stages"


def flat(xy):
    return np.zeros(len(np.atleast_2d(xy)))


def arc_lane(name: str, radius: float = 400.0, length: float = 1500.0, step: float = 2.0) -> Lane:
    """A lane turning left on a circle about (0, radius), starting at the origin heading +x."""
    th = np.arange(0.0, length + 1e-9, step) / radius
    return Lane(name, np.column_stack([radius * np.sin(th), radius - radius * np.cos(th)]))


def plan_view(m: np.ndarray, xy: np.ndarray, hfov_deg: float, near: float = 5.0, far: float = 25.0) -> np.ndarray:
    """Independent reference: defects near..far m ahead along the optical axis' plan heading,
    within half the horizontal FOV of it."""
    heading = math.atan2(m[1, 2], m[0, 2])
    d = xy - m[:2, 3]
    ahead = d[:, 0] * math.cos(heading) + d[:, 1] * math.sin(heading)
    side = -d[:, 0] * math.sin(heading) + d[:, 1] * math.cos(heading)
    return (ahead >= near) & (ahead <= far) & (np.degrees(np.abs(np.arctan2(side, ahead))) <= hfov_deg / 2)


def sparse_defects(lane: Lane, rng) -> DefectTargets:
    """A few potholes and cracks near the lane plus depressions (not a target type)."""
    s = np.array([300.0, 700.0, 1200.0, 500.0, 900.0])
    pts = lane.at(s) + rng.normal(0, 1.0, (len(s), 2))
    return DefectTargets(["P1", "P2", "C1", "X1", "X2"], ["pothole", "pothole", "crack", "depression", "depression"], pts)


# ------------------------------------------------------------------------------ shares
@pytest.mark.parametrize("share", [0.7, 0.3])
def test_share_of_views_with_a_target_defect_matches_the_request(share):
    lane = arc_lane("a")
    defects = sparse_defects(lane, np.random.default_rng(1))
    rig = ViewRig(hfov_deg=60.0)
    views = sample_views([lane], defects, flat, 200, rig=rig, share=share, seed=4, background="clear")
    targets = np.isin(defects.types, ["pothole", "crack"])
    seen = np.array([plan_view(v.cam_to_world, defects.xy[targets], 60.0).any() for v in views])
    assert abs(seen.mean() - share) <= 1.0 / len(views) + 1e-9
    aimed = [v for v in views if v.target is not None]
    assert len(aimed) == math.floor(len(views) * share + 1e-9)
    ids = np.array(defects.ids)[targets]
    for v in aimed:
        assert v.target in ids
        assert plan_view(v.cam_to_world, defects.xy[np.array(defects.ids) == v.target], 60.0)[0]
    assert share_with_targets(views) == pytest.approx(seen.mean())


def test_uniform_background_views_are_uniform_along_the_lane():
    lane = arc_lane("a", length=2000.0)
    defects = sparse_defects(lane, np.random.default_rng(2))
    views = sample_views([lane], defects, flat, 300, share=0.0, seed=9, background="uniform")
    s = np.array([v.s_m for v in views])
    hist, _ = np.histogram(s, bins=4, range=(0, 2000))
    assert hist.min() > 50          # 75 expected per quarter
    seen = np.array([plan_view(v.cam_to_world, defects.xy[:3], 60.0).any() for v in views])
    assert seen.mean() < 0.12       # three defects on 2 km: random views rarely see one


def test_no_target_defect_near_a_lane_is_one_clear_error():
    lane = arc_lane("a")
    far_away = DefectTargets(["P1"], ["pothole"], np.array([[0.0, -500.0]]))
    with pytest.raises(RoadtwinError, match="within 8.0 m of a lane"):
        sample_views([lane], far_away, flat, 5, share=0.5)


# ------------------------------------------------------------------------------ jitter
def _angles(m):
    f, r = m[:3, 2], m[:3, 0]
    pitch = math.degrees(math.asin(f[2]))
    yaw = math.degrees(math.atan2(f[1], f[0]))
    roll = math.degrees(math.asin(-r[2] / math.cos(math.radians(pitch))))
    return yaw, pitch, roll


@pytest.mark.parametrize("grade,crossfall", [(0.0, 0.0), (0.04, 0.02)])
def test_jitter_stays_within_bounds_and_follows_the_road(grade, crossfall):
    """A straight lane along +x at y = -1.75 on a plane z = grade*x + crossfall*y: height above
    the road, pitch (rig + grade), roll (rig + crossfall, right side lower), yaw and lateral
    offset all stay within the jitter half-widths, and use most of them."""
    lane = Lane("straight", np.column_stack([np.linspace(0, 800, 321), np.full(321, -1.75)]))
    ground = lambda xy: grade * np.atleast_2d(xy)[:, 0] + crossfall * np.atleast_2d(xy)[:, 1]  # noqa: E731
    rig, jit = ViewRig(mount_height_m=2.4, pitch_deg=-12.0, roll_deg=0.5), Jitter()
    defects = DefectTargets(["P1"], ["pothole"], np.array([[400.0, -1.0]]))
    views = sample_views([lane], defects, ground, 300, rig=rig, share=0.3, seed=3, jitter=jit)
    dev = {k: [] for k in ("height", "pitch", "roll", "yaw", "lateral")}
    for v in views:
        m = v.cam_to_world
        x, y, z = m[:3, 3]
        yaw, pitch, roll = _angles(m)
        dev["height"].append(z - ground(np.array([[x, y]]))[0] - rig.mount_height_m)
        dev["pitch"].append(pitch - rig.pitch_deg - math.degrees(math.atan(grade)))
        dev["roll"].append(roll - rig.roll_deg - math.degrees(math.atan(crossfall)))
        dev["yaw"].append(yaw)
        dev["lateral"].append(y + 1.75)
    bounds = {"height": jit.height_m, "pitch": jit.pitch_deg, "roll": jit.roll_deg, "yaw": jit.yaw_deg,
              "lateral": jit.lateral_m}
    for k, b in bounds.items():
        a = np.abs(np.array(dev[k]))
        slack = 0.05 if k in ("pitch", "roll") else 1e-6     # pitch/roll couple slightly on a slope
        assert a.max() <= b + slack, k
        assert a.max() >= 0.8 * b, k                         # the jitter is really drawn


# ------------------------------------------------------------------------------ determinism
def test_views_are_a_pure_function_of_seed_and_index():
    lane = arc_lane("a")
    defects = sparse_defects(lane, np.random.default_rng(5))
    a = sample_views([lane], defects, flat, 12, seed=21)
    b = sample_views([lane], defects, flat, 12, seed=21)
    assert all(np.array_equal(x.cam_to_world, y.cam_to_world) and x.as_dict() == y.as_dict() for x, y in zip(a, b))
    part = sample_views([lane], defects, flat, 4, seed=21, start=7)
    assert all(np.array_equal(x.cam_to_world, y.cam_to_world) for x, y in zip(a[7:11], part))
    other = sample_views([lane], defects, flat, 12, seed=22)
    assert not np.allclose(a[0].cam_to_world, other[0].cam_to_world)


# ------------------------------------------------------------------------------ lane chaining
def test_highway_lanes_chain_into_one_lane_per_direction_of_the_right_length(tmp_path):
    """The highway layout's 80 + 80 driving segments, read back from USD (float32 centrelines)
    and shuffled, chain into two lanes. A lane offset d to the left of a reference line of length
    L that turns by a net angle A has length L - d * A (parallel-curve length)."""
    sys.path.insert(0, str(STAGES))
    try:
        import make_highway as hw
    finally:
        sys.path.remove(str(STAGES))
    from roadtwin_core.render.scene import stage_lanes
    from roadtwin_core.usd import write_layout

    path = write_layout(hw.build(), tmp_path / "highway.usda")
    lanes = stage_lanes(path)
    assert len(lanes) == 160
    order = np.random.default_rng(0).permutation(len(lanes))
    chains = chain_lanes([lanes[i] for i in order])
    assert len(chains) == 2
    turn = math.radians(sum(math.copysign(d, r) for _, r, d in hw.CURVES))
    length = hw.total_length()
    by_side = {c.segments[0].split("_")[-1]: c for c in chains}
    assert by_side["r"].length == pytest.approx(length + hw.LANE / 2 * turn, abs=0.05)
    assert by_side["l"].length == pytest.approx(length - hw.LANE / 2 * turn, abs=0.05)
    assert len(by_side["r"].segments) == len(by_side["l"].segments) == 80
    assert by_side["r"].segments[0] == "hw_000_lane_r" and by_side["l"].segments[0] == "hw_079_lane_l"


def test_chaining_stops_at_junctions_and_cuts_rings():
    a = Lane("a", [[0, 0], [10, 0]])
    b = Lane("b", [[10, 0], [20, 0]])
    c = Lane("c", [[10, 0], [20, 1]])                         # a fork: a has two successors
    d = Lane("d", [[20, 0], [30, 0]])
    chains = chain_lanes([a, b, c, d])
    assert sorted(ch.segments for ch in chains) == [("a",), ("b", "d"), ("c",)]
    ring = [Lane(f"r{k}", [[math.cos(t0), math.sin(t0)], [math.cos(t1), math.sin(t1)]])
            for k, (t0, t1) in enumerate(zip(np.linspace(0, 2 * np.pi, 17)[:-1], np.linspace(0, 2 * np.pi, 17)[1:]))]
    chains = chain_lanes([Lane(l.id, l.points * 20) for l in ring])
    assert len(chains) == 1 and len(chains[0].segments) == 16        # 22.5 degree turns chain
    assert chains[0].length == pytest.approx(16 * 2 * 20 * math.sin(np.pi / 16))


# ------------------------------------------------------------------------------ ego lane
def _plane_depth(cam: Camera) -> np.ndarray:
    """Closed-form z-depth of the plane z = 0 seen from ``cam`` (0 where the ray misses it)."""
    k = cam.intrinsics
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    dc = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1)
    dz = dc @ cam.rotation[2]
    t = np.where(dz < -1e-9, -cam.position[2] / np.where(dz < -1e-9, dz, -1.0), 0.0)
    return t                                                   # the ray's camera z is 1 per unit t


def test_ego_lane_on_a_flat_road_matches_the_projected_lane_edges():
    """Straight lane along +x centred on y = 0, width 3.5; a camera 2.4 m up, 0.3 m left of the
    centre, yawed 2 degrees, pitched 12 degrees down. Each image row's ego-lane pixels must be
    the columns between the two projected edge lines y = +-1.75, up to one pixel."""
    cam = Camera(Intrinsics.from_fov(320, 200, 70.0), look_from((0.0, 0.3, 2.4), math.radians(2.0), math.radians(-12.0)))
    depth = _plane_depth(cam)
    lane = np.column_stack([np.linspace(-5, 400, 200), np.zeros(200)])
    mask = ego_lane_mask(cam, depth, lane, 3.5)
    k = cam.intrinsics
    cols = np.arange(k.width)
    checked = 0
    edges = []
    for side in (-1.75, 1.75):
        (u1, v1), (u2, v2) = cam.project(np.array([[20.0, side, 0.0], [120.0, side, 0.0]]))[0]
        edges.append((u1, v1, u2, v2))
    for row in range(k.height):
        if not (depth[row] > 0).all() or depth[row].max() > 150:
            continue                      # near the horizon the row spans kilometres
        us = sorted(u1 + (row - v1) * (u2 - u1) / (v2 - v1) for u1, v1, u2, v2 in edges)
        inside = (cols > us[0] + 1) & (cols < us[1] - 1)
        outside = (cols < us[0] - 1) | (cols > us[1] + 1)
        assert mask[row, inside].all() and not mask[row, outside].any(), row
        checked += 1
    assert checked > 100


def test_ego_lane_on_a_curve_follows_the_circle():
    """A lane on a circle of radius 150 m: ego pixels are those whose plane point lies within
    1.75 m of the circle (closed form), except pixels within one pixel of that region's edge."""
    from scipy.ndimage import maximum_filter, minimum_filter

    radius = 150.0
    th = np.linspace(-0.05, 1.0, 400)
    lane = np.column_stack([radius * np.sin(th), radius - radius * np.cos(th)])
    cam = Camera(Intrinsics.from_fov(256, 160, 60.0), look_from((0.0, 0.0, 2.4), 0.05, math.radians(-10.0)))
    depth = _plane_depth(cam)
    mask = ego_lane_mask(cam, depth, lane, 3.5)
    k = cam.intrinsics
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    dc = np.stack([(u - k.cx) / k.fx * depth, (v - k.cy) / k.fy * depth, depth], -1)
    p = dc @ cam.rotation.T + cam.position
    lat = np.hypot(p[..., 0], p[..., 1] - radius) - radius
    ok = (depth > 0) & (depth < 100)
    truth = ok & (np.abs(lat) <= 1.75)
    decided = ok & (minimum_filter(truth, 3) == maximum_filter(truth, 3)) & (minimum_filter(ok, 3) == 1)
    assert truth[decided].sum() > 2000 and (~truth[decided]).sum() > 2000
    assert np.array_equal(mask[decided], truth[decided])


def _straight(name, x0, y0, x1, y1, n=101) -> Lane:
    return Lane(name, np.column_stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)]))


def test_background_views_keep_off_a_roads_end_but_not_a_junction():
    """A 400 m two-way road that ends (a highway's ends: each lane's end is where the opposite
    lane starts, heading back): no background view stands within 25 m of a lane's end, where the
    camera would look past the road into the verge. Where another lane goes on (straight through
    a junction, or turning into the crossing road), views come up to the end as before."""
    empty = DefectTargets([], [], np.zeros((0, 2)))
    road = [_straight("east", 0, 0, 400, 0), _straight("west", 400, 3.5, 0, 3.5)]
    views = sample_views(road, empty, flat, 400, share=0.0, seed=3, background="uniform")
    ends = {"east": np.array([400.0, 0.0]), "west": np.array([0.0, 3.5])}
    to_end = np.array([np.linalg.norm(v.cam_to_world[:2, 3] - ends[v.lane_id]) for v in views])
    assert to_end.min() >= 25.0 - 1.0            # the jitter moves a camera by a metre at most sideways
    for follower in (_straight("on", 205, 0, 405, 0), _straight("turn", 206, 5, 206, 205)):
        lanes = [_straight("east", 0, 0, 200, 0), follower]
        views = sample_views(lanes, empty, flat, 400, share=0.0, seed=3, background="uniform")
        s = np.array([v.s_m for v in views if v.lane_id == "east"])
        assert (s > 200.0 - 25.0).sum() >= 10    # ~25 expected in the last 25 m of 'east'
