"""Defect-aware path planning (issue 7): grid maps, wheel/body collision, metrics, planners, CLI.

The scenario ``stages/defect_avoidance.usda`` is planned once per module through the ``plan``
command on the *layout* (so the command composes it first, as the README's
``roadtwin plan stages/defect_avoidance.usda --all -o OUT`` does); the composed town it leaves is
reused by every other scenario test. Metric and rasterization checks use hand-built grids and
meshes whose answers are computed here by hand.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from roadtwin_core import RoadtwinError
from roadtwin_core.cli.plan import plan
from roadtwin_core.planning.grid import GridMap, rasterize, rasterize_scene
from roadtwin_core.planning import (CollisionChecker, Footprint, parse_pose, path_metrics, plan_path, reference_path,
                                    transform)
from roadtwin_core.plugins import get_plugin_manager
from roadtwin_core.usd.town_reader import TownDefect, TownMesh, TownScene
from roadtwin_core.usd.validate import validate_stage
from roadtwin_core.vehicle import VehicleParams, paper_car

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "stages" / "defect_avoidance.usda"
PLANNERS = ("astar", "rrtstar", "lattice", "hybrid_astar")
START, GOAL = (4.0, -1.75, 0.0), (105.0, -1.75, 0.0)
PAPER = paper_car().footprint()   # the paper's car: what plan uses by default

app = typer.Typer()
app.command()(plan)


def run_cli(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """`plan LAYOUT --all -o OUT` once: composes the scenario into OUT/town and plans with all."""
    out = tmp_path_factory.mktemp("plan") / "all"
    result = run_cli(SCENARIO, "--all", "-o", out)
    assert result.exit_code == 0, (result.output, result.exception)
    return out


@pytest.fixture(scope="module")
def town(planned) -> Path:
    return planned / "town" / "town.usda"


@pytest.fixture(scope="module")
def grid(town) -> GridMap:
    return rasterize(town)


@pytest.fixture(scope="module")
def results(grid):
    """{(planner, collision): PlanResult} on the scenario."""
    return {(n, c): plan_path(grid, n, START, GOAL, footprint=PAPER, collision=c) for n in PLANNERS for c in ("wheel", "body")}


def open_grid(w=30.0, h=10.0, res=0.2, origin=(0.0, -5.0)) -> GridMap:
    ny, nx = int(round(h / res)), int(round(w / res))
    return GridMap.build(origin, res, np.ones((ny, nx), bool))


# --------------------------------------------------------------------------- rasterization
def _disc_mesh(cx, cy, r, depth, n=64, z0=0.0):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rim = np.column_stack([cx + r * np.cos(t), cy + r * np.sin(t), np.full(n, z0)])
    v = np.vstack([[cx, cy, z0 - depth], rim])
    f = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return v, f


def _rect_mesh(x0, x1, y0, y1, z=0.0):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_rasterize_circular_pothole_and_road_area():
    v_road, f_road = _rect_mesh(0.0, 12.0, -3.5, 3.5, z=0.3)
    v_walk, f_walk = _rect_mesh(0.0, 12.0, 3.5, 5.5, z=0.3)
    r, depth = 0.8, 0.06
    v_pot, f_pot = _disc_mesh(6.0, 0.5, r, depth, z0=0.3)
    scene = TownScene("Town", "synthetic", roads=[TownMesh("/Town/Roads/lane", "driving", v_road, f_road),
                                                   TownMesh("/Town/Roads/walk", "sidewalk", v_walk, f_walk)],
                      defects=[TownDefect("pot", "pothole", {"depthM": depth},
                                          [TownMesh("/Town/Defects/pot/lane", "pothole", v_pot, f_pot)])])
    g = rasterize_scene(scene, 0.2)
    cell = g.resolution ** 2
    area = 0.5 * 64 * r * r * math.sin(2 * math.pi / 64)  # the 64-gon's exact area
    assert abs(g.defect.sum() * cell - area) <= 3 * cell
    assert abs(g.drivable.sum() * cell - 12.0 * 7.0) <= 3 * cell   # the sidewalk is not drivable
    # Depth = road level (0.3, from the surrounding road cells) minus the cone surface.
    iy, ix = np.nonzero(g.defect)
    xy = g.cell_to_world(ix, iy)
    expect = depth * (1 - np.hypot(xy[:, 0] - 6.0, xy[:, 1] - 0.5) / r)
    assert np.allclose(g.depth[iy, ix], expect, atol=1e-4)
    assert np.allclose(g.road_height(np.array([[1.0, 0.0], [6.0, 0.5]])), 0.3)        # road level
    assert g.road_height(np.array([[6.0, 0.5]]), defects=True)[0] < 0.3 - 0.8 * depth  # pothole floor
    # Distance field: 0 on the defect, about (d - r) outside.
    assert g.distance[g.defect].max() == 0
    p = np.array([[6.0, -2.0]])
    assert abs(g.sample(g.distance, p)[0] - (2.5 - r)) < 0.25
    assert abs(g.clearance(p)[0] - (2.5 - r)) < 0.2


def test_rasterize_keeps_a_crack_thinner_than_a_cell():
    v_road, f_road = _rect_mesh(0.0, 10.0, -3.5, 3.5)
    x = np.linspace(3.0, 7.0, 41)      # a 4 m long, 4 cm wide, 2 cm deep strip along x, slightly slanted
    y = 0.13 + 0.05 * (x - 3.0)
    v = np.vstack([np.column_stack([x, y - 0.02, np.zeros_like(x)]), np.column_stack([x, y + 0.02, np.full_like(x, -0.02)])])
    n = len(x)
    f = np.array([[i, i + 1, n + i + 1] for i in range(n - 1)] + [[i, n + i + 1, n + i] for i in range(n - 1)])
    scene = TownScene("Town", "synthetic", roads=[TownMesh("/Town/Roads/lane", "driving", v_road, f_road)],
                      defects=[TownDefect("crack", "crack", {}, [TownMesh("/Town/Defects/crack/lane", "crack", v, f)])])
    g = rasterize_scene(scene, 0.2)
    iy, ix = np.nonzero(g.defect)
    xy = g.cell_to_world(ix, iy)
    assert len(xy) >= 4.0 / 0.2                                   # every cell along it
    assert np.all(np.abs(xy[:, 1] - (0.13 + 0.05 * (xy[:, 0] - 3.0))) < 0.2)
    assert g.depth[g.defect].max() == pytest.approx(0.02, abs=1e-6)


def test_rasterize_scenario(grid):
    cell = grid.resolution ** 2
    assert abs(grid.drivable.sum() * cell - 110.0 * 7.0) <= 3 * cell   # two 3.5 m lanes, 110 m
    from roadtwin_core.usd.town_reader import load_town

    scene = load_town(grid.source)
    assert len(grid.defect_ids) == 9
    for k, d in enumerate(scene.defects):
        assert grid.defect_ids[k] == d.id
        mask = grid.defect_index == k
        assert abs(mask.sum() * cell - d.attributes["areaM2"]) <= 3 * cell, d.id
        assert abs(grid.depth[mask].max() - d.attributes["depthM"]) < 0.02, d.id   # flat road: same depth


# --------------------------------------------------------------------------- metrics by hand
def test_metrics_straight_path_known_clearance():
    g = open_grid()
    defect = np.zeros(g.shape, bool)
    row = 37                       # cell centres at y = -5 + 37.5 * 0.2 = 2.5
    defect[row, :] = True
    g = GridMap.build(g.origin, g.resolution, g.drivable, defect)
    assert np.allclose(g.cell_to_world(0, row)[1], 2.5)
    poses = np.array([[5.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    m = path_metrics(g, poses, PAPER, reference_length=15.0)
    assert m.length_m == pytest.approx(15.0)
    assert m.deviation_pct == pytest.approx(0.0, abs=1e-9)
    assert m.smoothness_rad_per_m == 0.0
    # Left wheels at y = +1, 1.5 m from the defect row, right wheels at y = -1, 3.5 m: the mean is
    # 2.5 m, up to the along-row offset to the nearest cell centre (every 0.2 m): the wheels pass
    # x = 5.0, 5.1, ... (every half cell), alternately 0.1 m and 0 m off a centre.
    x = np.linspace(0.0, 15.0, 151)
    off = np.where(np.isclose((x * 10) % 2, 0), 0.1, 0.0)
    expect = 0.5 * (np.hypot(1.5, off).mean() + np.hypot(3.5, off).mean())
    assert m.mean_clearance_m == pytest.approx(expect, abs=1e-9)
    assert m.mean_clearance_m == pytest.approx(2.5, abs=3e-3)
    assert m.min_clearance_m == pytest.approx(1.5, abs=1e-9)
    assert not m.wheel_in_defect and not m.off_road and m.collision_free
    # The same path 1.4 m further left puts the left wheels on the defect row.
    m = path_metrics(g, poses + [0, 1.5, 0], PAPER, reference_length=15.0)
    assert m.wheel_in_defect and m.defects_under_wheels == ["defect"] and not m.collision_free


def test_metrics_one_known_turn():
    g = open_grid(40, 40, origin=(-15.0, -15.0))
    poses = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, math.pi / 2]])
    m = path_metrics(g, poses, PAPER)
    assert m.length_m == pytest.approx(20.0)
    assert m.total_turn_rad == pytest.approx(math.pi / 2)
    assert m.smoothness_rad_per_m == pytest.approx(math.pi / 2 / 20.0)
    assert m.reference_length_m == pytest.approx(math.hypot(10, 10))   # straight line on an open grid
    assert m.deviation_pct == pytest.approx(100 * (20 / math.hypot(10, 10) - 1))
    assert math.isinf(m.mean_clearance_m)                               # no defects at all
    # A turn on the spot (a repeated point) counts the same.
    spot = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 0.0, math.pi / 2], [10.0, 10.0, math.pi / 2]])
    assert path_metrics(g, spot, PAPER).smoothness_rad_per_m == pytest.approx(math.pi / 2 / 20.0)


def test_reference_path_follows_the_lanes_around_a_corner():
    # An L-shaped road: the reference is the string-pulled geodesic, not the blocked diagonal.
    res = 0.2
    mask = np.zeros((100, 100), bool)
    mask[:20, :] = True            # y in [0, 4): horizontal arm
    mask[:, 80:] = True            # x in [16, 20): vertical arm
    g = GridMap.build((0.0, 0.0), res, mask)
    ref = reference_path(g, (1.0, 2.0, 0.0), (18.0, 19.0, 0.0))
    length = float(np.linalg.norm(np.diff(ref, axis=0), axis=1).sum())
    assert len(ref) >= 3
    assert math.hypot(17, 17) < length < 17 + 17


def test_collision_levels_straddle():
    # A 0.6 m pothole between the wheels: free at wheel level, a collision at body level.
    g = open_grid()
    defect = np.zeros(g.shape, bool)
    iy, ix = np.mgrid[0:g.shape[0], 0:g.shape[1]]
    c = g.cell_to_world(ix, iy)
    defect[np.hypot(c[..., 0] - 12.0, c[..., 1]) < 0.3] = True
    g = GridMap.build(g.origin, g.resolution, g.drivable, defect)
    pose = np.array([[11.0, 0.0, 0.0]])
    assert CollisionChecker(g, PAPER, "wheel").free(pose)[0]
    assert not CollisionChecker(g, PAPER, "body").free(pose)[0]
    assert "body covers defect" in CollisionChecker(g, PAPER, "body").explain(pose[0])
    # One track width to the side, the right wheels roll through it.
    assert "rear-right wheel is inside defect" in CollisionChecker(g, PAPER, "wheel").explain((12.0, 1.0, 0.0))


def test_disc_shortcut_matches_point_lookup():
    rng = np.random.default_rng(3)
    g = open_grid()
    defect = rng.random(g.shape) < 0.01
    drivable = np.ones(g.shape, bool)
    drivable[:3], drivable[-3:] = False, False
    g = GridMap.build(g.origin, g.resolution, drivable, defect)
    poses = np.column_stack([rng.uniform(0, 30, 3000), rng.uniform(-5, 5, 3000), rng.uniform(-4, 4, 3000)])
    for level in ("wheel", "body"):
        ch = CollisionChecker(g, PAPER, level)
        exact = ~ch.blocked_at(transform(poses, ch.motion_local)).any(axis=1)
        assert np.array_equal(ch.free(poses), exact)


# --------------------------------------------------------------------------- planners on the scenario
def _tire_cells_hit_defects(grid: GridMap, poses: np.ndarray, vehicle: Footprint) -> bool:
    """Independent of the checker's point sets: tire centres and (inset) corners, by trigonometry,
    at every sample of the path's motion."""
    dense = CollisionChecker(grid, vehicle, "wheel").densify(poses)
    a, b = vehicle.tire_length_m / 2 - 1e-3, vehicle.tire_width_m / 2 - 1e-3
    local = [(0, 0), (a, b), (a, -b), (-a, b), (-a, -b)]
    c, s = np.cos(dense[:, 2]), np.sin(dense[:, 2])
    for wx, wy in vehicle.wheel_offsets():
        for dx, dy in local:
            x = dense[:, 0] + c * (wx + dx) - s * (wy + dy)
            y = dense[:, 1] + s * (wx + dx) + c * (wy + dy)
            if grid.sample(grid.defect, np.column_stack([x, y]), False).any():
                return True
    return False


@pytest.mark.parametrize("name", PLANNERS)
def test_wheel_level_paths_never_put_a_wheel_on_a_defect(results, grid, name):
    for level in ("wheel", "body"):
        r = results[(name, level)]
        m = r.metrics
        assert m.collision_free and not m.wheel_in_defect and not m.off_road, (name, level)
        assert not _tire_cells_hit_defects(grid, r.poses, PAPER), (name, level)
        assert np.allclose(r.poses[0], START) and np.allclose(r.poses[-1], GOAL)
    assert not results[(name, "body")].metrics.body_over_defect
    # Straddling is what wheel-level planning buys: the wheel-level path drives over defects
    # (between its wheels), the body-level path never does.
    assert results[(name, "wheel")].metrics.body_over_defect


@pytest.mark.parametrize("name", PLANNERS)
def test_wheel_level_paths_are_shorter_than_body_level(results, name):
    wheel, body = results[(name, "wheel")].metrics, results[(name, "body")].metrics
    assert wheel.length_m < body.length_m
    assert wheel.deviation_pct < body.deviation_pct


@pytest.mark.parametrize("level", ["wheel", "body"])
def test_hybrid_astar_and_lattice_are_smoother_than_astar_and_rrtstar(results, level):
    smooth = {n: results[(n, level)].metrics.smoothness_rad_per_m for n in PLANNERS}
    assert max(smooth["hybrid_astar"], smooth["lattice"]) < min(smooth["astar"], smooth["rrtstar"]), smooth


def test_planners_are_deterministic_and_match_the_command(results, planned, grid):
    with open(planned / "comparison.csv") as fh:
        rows = {r["planner"]: r for r in csv.DictReader(fh)}
    assert list(rows) == list(PLANNERS)    # registration order, the paper's
    for n in PLANNERS:
        assert rows[n]["status"] == "ok" and rows[n]["collision"] == "wheel"
        assert float(rows[n]["length_m"]) == pytest.approx(results[(n, "wheel")].metrics.length_m, abs=1e-3)
    again = plan_path(grid, "rrtstar", START, GOAL, footprint=PAPER, seed=0)
    assert np.array_equal(again.poses, results[("rrtstar", "wheel")].poses)


def test_registration():
    things = get_plugin_manager().registry("planners")
    assert list(things)[:4] == list(PLANNERS)
    for n in PLANNERS:
        t = things[n]
        assert t.name == n and t.description and hasattr(t.Params, "__dataclass_fields__")


@pytest.mark.parametrize("name", ["astar", "rrtstar"])
def test_motion_footprint_mode_on_an_open_square(name):
    # Heading = direction of motion, turns on the spot: fine where there is room.
    g = open_grid(40, 40, origin=(-5.0, -20.0))
    defect = np.zeros(g.shape, bool)
    iy, ix = np.mgrid[0:g.shape[0], 0:g.shape[1]]
    c = g.cell_to_world(ix, iy)
    defect[(np.abs(c[..., 0] - 15.0) < 1.5) & (np.abs(c[..., 1]) < 6.0)] = True   # a wide block ahead
    g = GridMap.build(g.origin, g.resolution, g.drivable, defect)
    r = plan_path(g, name, (0.0, 0.0, 0.0), (28.0, 0.0, 0.0), footprint=PAPER, params={"footprint": "motion"}, seed=1)
    assert r.metrics.collision_free and not r.metrics.wheel_in_defect
    assert r.metrics.length_m > 28.0


def test_dubins_and_lattice_primitives():
    from roadtwin_planners.hybrid_astar import dubins_path
    from roadtwin_planners.lattice import StateLattice

    rng = np.random.default_rng(0)
    for _ in range(30):
        q0 = np.array([*rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi)])
        q1 = np.array([*rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi)])
        paths = dubins_path(q0, q1, 4.0)
        assert paths, (q0, q1)           # a Dubins path always exists
        length = np.linalg.norm(np.diff(np.vstack([q0[None], paths[0]])[:, :2], axis=0), axis=1).sum()
        assert length >= np.hypot(*(q1[:2] - q0[:2])) - 1e-6
    lattice = StateLattice()
    from roadtwin_core import make_params

    prims = lattice.primitives(PAPER, make_params(lattice.Params, {}, "lattice"))
    assert len(prims) >= 9
    for curve, cost, _ in prims:
        d = np.diff(curve[:, :2], axis=0)
        seg = np.linalg.norm(d, axis=1)
        assert seg.max() <= 0.1 + 1e-9 and cost >= seg.sum()


# --------------------------------------------------------------------------- the command
def test_command_single_planner_outputs(town, tmp_path):
    out = tmp_path / "one"
    result = run_cli(town, "--planner", "lattice", "--collision", "body", "-o", out, "--seed", "3")
    assert result.exit_code == 0, (result.output, result.exception)
    assert "lattice" in result.output
    for name in ("path.csv", "path.usda", "metrics.json", "plot.png"):
        assert (out / name).stat().st_size > 0
    with open(out / "path.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["x", "y", "z", "yaw"]
    assert float(rows[0]["x"]) == pytest.approx(4.0) and float(rows[-1]["x"]) == pytest.approx(105.0)
    meta = json.loads((out / "metrics.json").read_text())
    assert meta["planner"] == "lattice" and meta["collision"] == "body" and meta["seed"] == 3
    assert meta["metrics"]["collision_free"] and not meta["metrics"]["wheel_in_defect"]
    assert not [f for f in validate_stage(out / "path.usda") if f.severity == "Error"]
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out / "path.usda"))
    assert stage.GetDefaultPrim().GetName() == "Town"
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1
    curve = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Town/Plans/lattice_body/Path"))
    assert curve and curve.GetTypeAttr().Get() == "linear"
    assert len(curve.GetPointsAttr().Get()) == len(rows)
    assert stage.GetPrimAtPath("/Town/Roads")        # the town comes in through the sublayer
    assert stage.GetPrimAtPath("/Town/Plans/lattice_body").GetAttribute("roadtwin:plan:lengthM").Get() > 100


def test_command_all_outputs(planned):
    for n in PLANNERS:
        for name in ("path.csv", "path.usda", "metrics.json", "plot.png"):
            assert (planned / n / name).exists()
    assert (planned / "comparison.png").stat().st_size > 0
    # The curve layers reference the town composed into the output folder by a relative path.
    assert "@../town/town.usda@" in (planned / "astar" / "path.usda").read_text()
    assert not [f for f in validate_stage(planned / "paths.usda") if f.severity == "Error"]


@pytest.mark.parametrize("args, message", [
    (["--start", "4,5,0"], "start (4, 5, 0) is not a valid pose: its rear-left wheel is off the drivable lanes"),
    (["--start", "14,-0.75,0"], "start (14, -0.75, 0) is not a valid pose: its rear-right wheel is inside defect "
                                "straddle_a (pothole)"),
    (["--goal", "89.9,-1.75,0"], "goal (89.9, -1.75, 0) is not a valid pose: its rear-right wheel is inside defect "
                                 "right_wheel (pothole)"),
    (["--goal", "60,-1.75,0", "--collision", "body"],
     "goal (60, -1.75, 0) is not a valid pose: its front-left wheel is inside defect wide_depression (depression)"),
    (["--start", "10,-1.75,0", "--collision", "body"],
     "start (10, -1.75, 0) is not a valid pose: its body covers defect straddle_a (pothole) (body-level collision)"),
    (["--planner", "dijkstra"], "unknown planner 'dijkstra' (known: astar, hybrid_astar, lattice, rrtstar)"),
    (["--start", "4,-1.75"], "--start must be X,Y,YAW (metres, metres, radians), got '4,-1.75'"),
    (["--collision", "tire"], "unknown collision level 'tire' (known: wheel, body)"),
    (["--resolution", "0"], "--resolution must be a positive number of metres, got 0.0"),
    (["--all", "--planner", "astar"], "give --planner NAME or --all, not both"),
])
def test_command_bad_input(town, tmp_path, args, message):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("earlier output")
    result = run_cli(town, "-o", out, *args)
    assert isinstance(result.exception, RoadtwinError), result.output
    assert str(result.exception) == message
    assert (out / "keep.txt").read_text() == "earlier output"     # an earlier output stays intact


def test_unreachable_goal():
    # Two road pieces with no drivable connection.
    g = open_grid(30, 8, origin=(0.0, -4.0))
    drivable = g.drivable.copy()
    drivable[:, 70:80] = False
    g = GridMap.build(g.origin, g.resolution, drivable)
    with pytest.raises(RoadtwinError, match="goal is unreachable: no drivable connection from the start"):
        plan_path(g, "astar", (2.0, 0.0, 0.0), (22.0, 0.0, 0.0), footprint=PAPER)
    # Connected, but a defect band across the whole road: no wheel can get past it.
    g = open_grid(30, 8, origin=(0.0, -4.0))
    defect = np.zeros(g.shape, bool)
    defect[:, 70:75] = True
    g = GridMap.build(g.origin, g.resolution, g.drivable, defect)
    for name in ("astar", "hybrid_astar"):
        with pytest.raises(RoadtwinError, match=f"planner {name}: found no wheel-level collision-free path"):
            plan_path(g, name, (2.0, 0.0, 0.0), (22.0, 0.0, 0.0), footprint=PAPER, params={"max_expansions": 20000})


def test_parse_pose_and_vehicle():
    assert parse_pose(" 1, -2.5 ,0.3", "x") == (1.0, -2.5, 0.3)
    with pytest.raises(RoadtwinError, match="x must be X,Y,YAW"):
        parse_pose("1,nan,0", "x")
    v = PAPER   # the paper's car: 2.0 m track, 3.0 m wheelbase, 0.2 m tires, 0.6 rad lock
    assert (v.track_m, v.wheelbase_m, v.tire_width_m) == (2.0, 3.0, 0.2)
    assert v.straddle_gap_m == pytest.approx(1.8)
    assert v.min_turn_radius_m == pytest.approx(3.0 / math.tan(0.6))
    with pytest.raises(RoadtwinError, match="tire_width_m .* must be less than track_front_m"):
        VehicleParams(track_front_m=0.15, track_rear_m=0.15, tire_width_m=0.2).check()
    with pytest.raises(RoadtwinError, match="track_front_m == track_rear_m"):
        VehicleParams(track_front_m=1.5, track_rear_m=1.6).footprint()


def test_footprint_is_the_physics_vehicle():
    """One vehicle: the footprint planning uses is read off VehicleParams (wheel centres at
    (0, +-track/2) and (wheelbase, +-track/2) from the rear axle), for any car."""
    car = VehicleParams(name="van", wheelbase_m=3.3, cg_to_front_axle_m=1.4, track_front_m=1.7, track_rear_m=1.7,
                        body_length_m=5.2, rear_overhang_m=1.0).check()
    fp = car.footprint()
    np.testing.assert_allclose(fp.wheel_offsets(), [[0, 0.85], [0, -0.85], [3.3, 0.85], [3.3, -0.85]])
    assert fp.tire_width_m == car.tire_width_m and fp.tire_length_m == car.tire_contact_length_m
    x0, x1, _, _ = fp.body_rect()
    assert (x0, x1) == pytest.approx((-1.0, 4.2))


def test_plan_sweep_needs_the_sweep_of_the_planned_car(town, tmp_path):
    """`plan --vehicle FILE --sweep DIR`: the car planned for is the car whose vibration decides.
    A sweep of the paper car cannot decide for the default sedan; the sedan's own sweep can, and
    the path is then planned with the sedan's footprint (1.55 m track, not the paper car's 2.0 m)."""
    from roadtwin_core.vehicle import DEFAULT_CAR
    from roadtwin_core.apps.sweep.run import dataclass_dict

    sedan = ROOT / "roadtwin_core" / "vehicle" / "default_car.toml"
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "recommendations.json").write_text("[]")
    (sweep / "summary.json").write_text(json.dumps({"vehicles": {"paper_car": dataclass_dict(paper_car())}}))
    result = run_cli(town, "-p", "astar", "--vehicle", sedan, "--sweep", sweep, "-o", tmp_path / "out")
    assert isinstance(result.exception, RoadtwinError), result.output
    assert "not the car being planned for, default_car (track 1.55 m" in str(result.exception)
    (sweep / "summary.json").write_text(json.dumps({"vehicles": {"default_car": dataclass_dict(DEFAULT_CAR)}}))
    result = run_cli(town, "-p", "astar", "--vehicle", sedan, "--sweep", sweep, "-o", tmp_path / "out")
    assert result.exit_code == 0, (result.output, result.exception)
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["vehicle"]["track_m"] == 1.55 and metrics["vehicle"]["wheelbase_m"] == 2.7
