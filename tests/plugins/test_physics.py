"""Vehicle physics: validation against independent references, cross-backend agreement, the
paper's two findings, the sweep command and its bad input.

References (none of them is the code's own output):

* quarter car on ISO 8608 roads vs the closed form for white road-velocity input
  var(body accel) = G0 (cs^2 kt + ks^2 (ms + mu)) / (4 cs ms^2), G0 = (2 pi n0)^2 Gd(n0) v.
  Convention: Gd is the standard's *one-sided* spatial displacement PSD (m^3); G0 is then the
  one-sided temporal PSD of the road's vertical velocity per Hz, and the variance is
  G0 * integral_0^inf |H(2 pi f)|^2 df (checked numerically here too). The road is synthesised
  here (random phases, exact one-sided amplitudes sqrt(2 Gd dn)) over 0.01..5 cycles/m, whose
  truncation error at 20 m/s is computed below from the transfer function (< 1 %).
* free fall (z = z0 - g t^2 / 2, the accelerometer reads 0) and static sag of the full car
  (per corner: sprung load / ks + (sprung load + unsprung weight) / kt, i.e. m g / k_eff with
  ks and kt in series; the CG drop is the axle drops interpolated at the CG).
* a step of known height: every wheel centre (and the body) ends up exactly that much higher.
* ISO 2631-1 Table 3 values of the Wk weighting.

The warp kernels compile once (about 20-60 s on a CPU, then cached in ~/.cache/warp).
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from roadtwin_core import PluginManager, RoadtwinError
from roadtwin_core import plugins as plugins_mod
from roadtwin_core.apps.sweep import SweepConfig, build_matrix, compute_rows, parse_speeds, recommend
from roadtwin_core.vehicle import (DEFAULT_CAR, QuarterCarParams, RoadMesh, SimParams, VehicleParams,
                                   VehicleRun, comfort_band, grid_mesh, load_vehicle,
                                   step_road, straight_road, straight_road_scenario,
                                   vehicle_to_toml, wk_digital, wk_magnitude)
from roadtwin_core.vehicle.vehicle import GRAVITY

pytest.importorskip("warp")
import roadtwin_warp_physics  # noqa: E402

try:
    import roadtwin_pybullet
    import pybullet  # noqa: F401
    HAVE_PYBULLET = True
except ImportError:  # pragma: no cover
    HAVE_PYBULLET = False


@pytest.fixture(scope="module")
def pm():
    m = PluginManager(load_entry_points=False)
    m.register(roadtwin_warp_physics, name="warp_physics")
    if HAVE_PYBULLET:
        m.register(roadtwin_pybullet, name="pybullet")
    return m


@pytest.fixture(scope="module")
def warp(pm):
    return pm.get("physics_backends", "warp")


@pytest.fixture(scope="module")
def flat():
    return straight_road(80.0, width_m=6.0)[1]


# ----------------------------------------------------------------------------- vehicle files
def test_vehicle_files_round_trip(tmp_path):
    (tmp_path / "car.toml").write_text(vehicle_to_toml(DEFAULT_CAR))
    assert load_vehicle(tmp_path / "car.toml") == DEFAULT_CAR
    (tmp_path / "light.json").write_text(json.dumps({"extends": "default", "body": {"sprung_mass_kg": 1100}}))
    light = load_vehicle(tmp_path / "light.json")
    assert light.sprung_mass_kg == 1100 and light.name == "light" and light.wheelbase_m == DEFAULT_CAR.wheelbase_m
    q = tmp_path / "q.toml"
    q.write_text('model = "quarter"\nextends = "default"\nsprung_mass_kg = 250.0\n')
    assert isinstance(load_vehicle(q), QuarterCarParams)


@pytest.mark.parametrize("text, needle", [
    ('sprung_mass_kg = 1300.0\n', "missing parameter(s)"),
    ('extends = "default"\nsprung_mass_kg = -5.0\n', "sprung_mass_kg must be > 0"),
    ('extends = "default"\ntire_stiffness_n_per_m = 0.0\n', "tire_stiffness_n_per_m must be > 0"),
    ('extends = "default"\nwheelbase_m = nan\n', "wheelbase_m must be finite"),
    ('extends = "default"\nroll_inertia_kgm2 = 9000.0\n', "no rigid body has such inertias"),
    ('extends = "default"\ncg_to_front_axle_m = 3.0\n', "cg_to_front_axle_m (3.0) must be less than wheelbase_m"),
    ('extends = "default"\nstop_stiffness_n_per_m = 1000.0\n', "not a stop"),
    ('extends = "default"\ntire_stiffness_n_per_m = 20000.0\n', "static tire deflection"),
    ('extends = "default"\nspring_rate = 3.0\n', "unknown parameter(s) spring_rate"),
    ('extends = "default"\nsprung_mass_kg = "heavy"\n', "sprung_mass_kg must be a number"),
    ('this is not toml', "cannot parse"),
])
def test_vehicle_file_errors(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(RoadtwinError) as err:
        load_vehicle(path)
    msg = str(err.value)
    assert needle in msg and str(path) in msg and "\n" not in msg


# ----------------------------------------------------------------------------- metrics
# ISO 2631-1:1997 Table 3, Wk (x 1000)
ISO_WK = {0.5: 418, 1.0: 482, 2.0: 531, 4.0: 967, 6.3: 1054, 8.0: 1036, 12.5: 902, 16.0: 768, 31.5: 405, 63.0: 186}


def test_wk_weighting_matches_the_standard():
    from scipy import signal

    f = np.array(list(ISO_WK))
    ref = np.array(list(ISO_WK.values())) / 1000
    assert np.allclose(wk_magnitude(f), ref, rtol=0.01)
    b, a = wk_digital(1000.0)
    _, h = signal.freqz(b, a, worN=f[f <= 31.5], fs=1000.0)
    assert np.allclose(np.abs(h), ref[f <= 31.5], rtol=0.03)


def test_comfort_bands():
    assert comfort_band(0.2) == "not uncomfortable"
    assert comfort_band(0.4) == "a little uncomfortable"
    assert comfort_band(0.7) == "fairly uncomfortable"
    assert comfort_band(1.2) == "uncomfortable"
    assert comfort_band(1.8) == "very uncomfortable"
    assert comfort_band(3.0) == "extremely uncomfortable"


# ----------------------------------------------------------------------------- validation (warp)
def iso8608_profile(n_points: int, dx: float, gd0: float, band: tuple[float, float], rng) -> np.ndarray:
    """Random-phase synthesis with the standard's one-sided PSD Gd(n) = Gd(n0) (n/n0)^-2."""
    n = np.fft.rfftfreq(n_points, d=dx)
    dn = n[1]
    amp = np.zeros_like(n)
    inside = (n >= band[0]) & (n <= band[1])
    amp[inside] = np.sqrt(2 * gd0 * (0.1 / n[inside]) ** 2 * dn)
    spec = amp * np.exp(1j * rng.uniform(0, 2 * np.pi, len(n))) * n_points / 2
    return np.fft.irfft(spec, n_points)


def test_quarter_car_matches_closed_form_on_iso8608_roads(warp):
    qc = QuarterCarParams()
    ms, mu, ks, cs, kt = (qc.sprung_mass_kg, qc.unsprung_mass_kg, qc.spring_n_per_m, qc.damper_ns_per_m,
                          qc.tire_stiffness_n_per_m)
    v, T, dx, band, gd0, n_real = 20.0, 60.0, 0.02, (0.01, 5.0), 64e-6, 12   # class B
    # the band's truncation error, from the transfer function (not from the simulator)
    w = 2 * np.pi * np.logspace(-4, 4, 400001)
    s = 1j * w
    k, c = ks + cs * s, kt
    zs = k * c / ((ms * s * s + k) * (mu * s * s + k + c) - k * k)
    h2 = np.abs(s * zs) ** 2                       # body acceleration / road velocity
    full = np.trapezoid(h2, w) / (2 * np.pi)
    closed = (cs ** 2 * kt + ks ** 2 * (ms + mu)) / (4 * cs * ms ** 2)
    assert full == pytest.approx(closed, rel=1e-3)
    inb = (w >= 2 * np.pi * band[0] * v) & (w <= 2 * np.pi * band[1] * v)
    assert 1 - np.trapezoid(h2[inb], w[inb]) / (2 * np.pi) / closed < 0.01
    # the roads: one 1 m wide strip per realisation, side by side
    rng = np.random.default_rng(8608)
    npts = int((v * T + 30) / dx)
    npts += npts % 2
    x = np.arange(npts) * dx
    verts, faces = [], []
    for r in range(n_real):
        z = iso8608_profile(npts, dx, gd0, band, rng)
        m = grid_mesh(x, np.array([3.0 * r - 0.5, 3.0 * r + 0.5]), np.vstack([z, z]))
        faces.append(m.faces + sum(len(q) for q in verts))
        verts.append(m.vertices)
    road = RoadMesh(np.concatenate(verts), np.concatenate(faces))
    runs = [VehicleRun(qc, np.array([[0.0, 3.0 * r], [x[-1], 3.0 * r]]), 10.0, v, T) for r in range(n_real)]
    tr = warp.simulate(road, runs, SimParams(imu_rate_hz=1000.0))
    keep = tr.t > 3.0
    var = np.var(tr.acc[:, keep, 2], axis=1)
    g0 = (2 * np.pi * 0.1) ** 2 * gd0 * v
    ratio = var.mean() / (g0 * closed)
    assert abs(ratio - 1) < 0.03, ratio
    assert np.nanmin(tr.tire_f[:, keep, 0]) > 0        # never airborne: the linear theory applies


def test_free_fall_then_contact(warp, flat):
    car = dataclasses.replace(DEFAULT_CAR, rebound_travel_m=0.3)   # s = 0 (free springs) inside the travel
    drop = 0.2
    z0 = drop + car.tire_radius_m + max(c["e_free"] for c in car.to_plain()["corners"])
    run = VehicleRun(car, np.array([[0.0, 0.0], [80.0, 0.0]]), 20.0, 0.0, 0.6,
                     initial_state={"q": [z0, 0.0, 0.0], "qd": [0.0, 0.0, 0.0], "s": [0.0] * 4, "sd": [0.0] * 4})
    tr = warp.simulate(flat, [run], SimParams(imu_rate_hz=1000.0))
    t, z = tr.t, tr.pose[0, :, 2]
    lowest = (tr.wheel_z[0] - car.tire_radius_m).min(axis=1)       # lowest wheel bottom above the road
    t_contact = t[np.argmax(lowest <= 0.0)]
    assert t_contact == pytest.approx(math.sqrt(2 * drop / GRAVITY), abs=0.002)   # the front wheels hang lowest
    air = t < t_contact - 0.005
    assert np.abs(z[air] - (z0 - 0.5 * GRAVITY * t[air] ** 2)).max() < 2e-3
    assert np.abs(tr.acc[0, air]).max() < 1e-2                      # an accelerometer in free fall reads 0
    assert tr.acc[0, t > t_contact + 0.01, 2].max() > GRAVITY          # then the tires push


def test_static_sag_full_vehicle(warp, flat):
    car = dataclasses.replace(DEFAULT_CAR, rebound_travel_m=0.3)
    p = car.to_plain()
    c = p["corners"]
    # free springs, undeformed tires touching the road: body pitched so both axles fit
    zf, zr = car.tire_radius_m + c[0]["e_free"], car.tire_radius_m + c[2]["e_free"]
    a, b, L = car.cg_to_front_axle_m, car.cg_to_rear_axle_m, car.wheelbase_m
    z0 = zr + (zf - zr) * b / L
    run = VehicleRun(car, np.array([[0.0, 0.0], [80.0, 0.0]]), 20.0, 0.0, 6.0,
                     initial_state={"q": [z0, 0.0, -math.atan((zf - zr) / L)], "s": [0.0] * 4})
    tr = warp.simulate(flat, [run])
    w = [car.sprung_mass_kg * GRAVITY * b / L / 2, car.sprung_mass_kg * GRAVITY * a / L / 2]   # corner loads
    ks = [car.spring_front_n_per_m, car.spring_rear_n_per_m]
    mu_g = car.unsprung_mass_kg * GRAVITY
    sag = [w[i] / ks[i] + (w[i] + mu_g) / car.tire_stiffness_n_per_m for i in range(2)]   # series springs
    expected = (b * sag[0] + a * sag[1]) / L
    assert z0 - tr.pose[0, -1, 2] == pytest.approx(expected, rel=0.005)
    assert abs(tr.pose[0, -1, 4]) < 1e-4 and abs(tr.pose[0, -1, 3]) < 1e-4        # level at rest
    total = tr.tire_f[0, -1].sum()
    assert total == pytest.approx(car.total_mass_kg * GRAVITY, rel=1e-3)


def test_wheel_crossing_a_step(warp):
    h = 0.03
    road = step_road(40.0, x_step=10.0, height_m=h)
    v = 2.0
    run = VehicleRun(DEFAULT_CAR, np.array([[0.0, 0.0], [40.0, 0.0]]), 5.0, v, 9.0)
    tr = warp.simulate(road, [run])
    t = tr.t
    before = t < 1.0                                    # CG at x < 7: every wheel before the step
    after = t > 8.0                                     # rear axle crossed at t ~ 3.3 s
    wz0 = tr.wheel_z[0, before].mean(axis=0)
    wz1 = tr.wheel_z[0, after].mean(axis=0)
    assert np.allclose(wz1 - wz0, h, atol=1e-3), wz1 - wz0
    assert tr.pose[0, after, 2].mean() - tr.pose[0, before, 2].mean() == pytest.approx(h, abs=1e-3)
    assert tr.acc[0, :, 2].max() > GRAVITY + 1.0        # the step was felt


def test_warp_is_deterministic(warp):
    sc = straight_road_scenario(60.0)
    cfg = SweepConfig(speeds_kmh=[20.0])
    specs = build_matrix(sc, cfg)
    runs = [VehicleRun(DEFAULT_CAR, s.path, s.s0, s.speed_kmh / 3.6, s.duration) for s in specs]
    a = warp.simulate(sc.road, runs)
    b = warp.simulate(sc.road, runs)
    assert np.array_equal(a.acc, b.acc, equal_nan=True) and np.array_equal(a.gyro, b.gyro, equal_nan=True)


# ----------------------------------------------------------------------------- cross-backend and findings
def sweep_rows(backend, speeds, surface=None):
    from roadtwin_core.apps.sweep import run_sweep

    res = run_sweep(straight_road_scenario(60.0, surface), backend, SweepConfig(speeds_kmh=speeds))
    return {(r["defect"], r["speed_kmh"]): r for r in res["rows"]}, res


@pytest.mark.skipif(not HAVE_PYBULLET, reason="pybullet not installed")
def test_cross_backend_g_and_the_papers_findings(pm):
    speeds = [10.0, 30.0, 50.0]
    w, _ = sweep_rows(pm.get("physics_backends", "warp"), speeds)
    p, _ = sweep_rows(pm.get("physics_backends", "pybullet"), speeds)
    for key in w:
        assert not w[key]["off_road"] and not p[key]["off_road"]
        assert p[key]["g"] == pytest.approx(w[key]["g"], rel=0.15), key
        assert p[key]["aw"] == pytest.approx(w[key]["aw"], rel=0.15), key
    for rows in (w, p):
        deep = [rows[("large_deep", s)]["g"] for s in speeds]
        small = [rows[("small_shallow", s)]["g"] for s in speeds]
        assert deep[0] < deep[1] < deep[2]          # large deep pothole: slowing down reduces g
        assert small[2] < small[1]                  # small shallow one: a higher speed reduces g


@pytest.mark.skipif(not HAVE_PYBULLET, reason="pybullet not installed")
def test_quarter_car_same_on_both_backends(pm):
    road = straight_road(40.0, surface="iso8608:C", seed=3)[1]
    qc = QuarterCarParams()
    runs = [VehicleRun(qc, np.array([[0.0, y], [40.0, y]]), 2.0, v, 2.0) for y, v in ((0.0, 15.0), (1.0, 8.0))]
    a = pm.get("physics_backends", "warp").simulate(road, runs)
    b = pm.get("physics_backends", "pybullet").simulate(road, runs)
    assert np.nanstd(a.acc[:, :, 2]) > 0.5                        # the road is felt
    assert np.allclose(a.acc, b.acc, atol=1e-3, equal_nan=True)
    assert np.allclose(a.wheel_z, b.wheel_z, atol=1e-5, equal_nan=True)


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_PYBULLET, reason="pybullet not installed")
def test_full_speed_sweep_both_backends(pm):
    speeds = parse_speeds("5:60:5")
    w, resw = sweep_rows(pm.get("physics_backends", "warp"), speeds, "iso8608:B")
    p, _ = sweep_rows(pm.get("physics_backends", "pybullet"), speeds, "iso8608:B")
    for key in w:
        assert p[key]["g"] == pytest.approx(w[key]["g"], rel=0.15)
    deep = [w[("large_deep", s)]["g"] for s in speeds]
    small = [w[("small_shallow", s)]["g"] for s in speeds]
    assert deep[0] == min(deep) and max(deep) > 2 * deep[0]
    peak = int(np.argmax(small))
    assert 0 < peak < len(speeds) - 1 and small[-1] < 0.85 * small[peak]
    recs = {r["defect"]: r for r in resw["recommendations"]}
    assert recs["large_deep"]["recommended_speed_kmh"] <= 10 and recs["small_shallow"]["recommended_speed_kmh"] >= 40


@pytest.mark.skipif(not HAVE_PYBULLET, reason="pybullet not installed")
def test_pybullet_mesh_chunks_and_static_rest(flat):
    from roadtwin_pybullet import sim as bullet

    one = bullet.BulletVehicleSim(flat.vertices, flat.faces)
    many = bullet.BulletVehicleSim(flat.vertices, flat.faces, chunk_triangles=2000)
    assert one.n_chunks == 1 and many.n_chunks > 3
    veh = [{"params": DEFAULT_CAR.to_plain(), "path": np.array([[0.0, 0.0], [80.0, 0.0]]), "s0": 30.0,
            "speed": 0.0, "duration": 0.3}]
    a, b = one.run(veh), many.run(veh)
    one.close()
    many.close()
    loads = [c["load"] + DEFAULT_CAR.unsprung_mass_kg * GRAVITY for c in DEFAULT_CAR.to_plain()["corners"]]
    assert np.allclose(a["tire_f"][0, -1], loads, rtol=1e-3)
    assert np.allclose(a["tire_f"][0, -1], b["tire_f"][0, -1], rtol=1e-6)


# ----------------------------------------------------------------------------- the command
@pytest.fixture
def cli(pm, monkeypatch):
    from roadtwin_core.cli.sweep import sweep

    monkeypatch.setattr(plugins_mod, "_manager", pm)
    app = typer.Typer()

    @app.callback()
    def main() -> None:
        """roadtwin (test)"""

    app.command()(sweep)
    runner = CliRunner()
    return lambda *args: runner.invoke(app, ["sweep", *map(str, args)])


def test_cli_sweep_on_a_test_road(cli, tmp_path):
    out = tmp_path / "out"
    r = cli("--surface", "iso8608:B", "--speeds", "10,40", "--defects", "small_shallow", "--rerun", "-o", out)
    assert r.exit_code == 0, (r.output, r.exception)
    names = {p.name for p in out.iterdir()}
    try:
        import pyarrow.parquet as pq

        assert pq.read_table(out / "runs.parquet").num_rows == 2
    except ImportError:
        assert "no runs.parquet" in r.output
    try:
        import rerun  # noqa: F401

        assert "sweep.rrd" in names
    except ImportError:
        assert "rerun-sdk is not installed" in r.output
    assert {"runs.csv", "recommendations.csv", "recommendations.json", "traces.npz", "g_vs_speed.png",
            "imu_small_shallow.png", "summary.json"} <= names
    import csv

    rows = list(csv.DictReader((out / "runs.csv").open()))
    assert len(rows) == 2 and {r["defect"] for r in rows} == {"small_shallow"}
    for col in ("backend", "defect", "speed_kmh", "lateral_offset_m", "g", "aw", "rms_az", "comfort", "peak_az"):
        assert col in rows[0]
    assert all(float(r["g"]) > 0 for r in rows)
    npz = np.load(out / "traces.npz")
    assert npz["acc"].shape[0] == 2 and npz["acc"].shape[2] == 3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == 2 and summary["realtime_factor"] > 0


def write_town_layout(path):
    """A 30 m x 7 m one-lane layout with one pinned 8 cm pothole (FixedDefect) and no random ones."""
    from roadtwin_core import ComposeRules, FixedDefect, RoadSegment, TownLayout
    from roadtwin_core.usd import write_layout

    seg = RoadSegment("lane", "driving", np.array([[0, -3.5], [30, -3.5], [30, 3.5], [0, 3.5]], float),
                      np.array([[0, 1, 2], [0, 2, 3]]), centerline=np.array([[0.0, 0.0], [30.0, 0.0]]))
    pot = FixedDefect("pothole_1", "pothole", {"radius_m": 0.4, "depth_m": 0.08, "elongation": 1.0,
                                               "irregularity": 0.05}, 15.0, -0.775, 0.0, seed=3)
    layout = TownLayout("Town", [seg], ComposeRules(defect_count=0, surface="flat"), fixed=[pot])
    write_layout(layout, path, "physics test layout")
    return path


def test_cli_sweep_on_a_town(cli, tmp_path):
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.usd import load_town
    from roadtwin_core.vehicle import town_scenario

    layout = write_town_layout(tmp_path / "layout.usda")
    compose(layout, tmp_path / "town", preview=False, executor="serial", pm=PluginManager())
    town = tmp_path / "town" / "town.usda"
    scene = load_town(town)
    assert [d.id for d in scene.defects] == ["pothole_1"]
    r = cli(town, "--speeds", "10,30", "--defects", "pothole_1", "--no-plots", "-o", tmp_path / "sw")
    assert r.exit_code == 0, (r.output, r.exception)
    import csv

    rows = list(csv.DictReader((tmp_path / "sw" / "runs.csv").open()))
    assert [r["defect"] for r in rows] == ["pothole_1", "pothole_1"]
    assert all(r["off_road"] == "False" and float(r["g"]) > 0.3 for r in rows)
    # the baseline road has the pothole filled in: flat again around its centre
    sc = town_scenario(scene)
    near = np.linalg.norm(sc.baseline.vertices[:, :2] - [15.0, -0.775], axis=1) < 0.3
    assert near.sum() > 10
    assert sc.road.vertices[near, 2].min() < -0.05 and np.abs(sc.baseline.vertices[near, 2]).max() < 1e-3


@pytest.mark.parametrize("args, needle", [
    (["--surface", "flat", "--defects", "nope"], "no defect 'nope'"),
    (["--surface", "flat", "--speeds", "0:20:10"], "every speed must be > 0"),
    (["--surface", "flat", "--speeds", "-10"], "every speed must be > 0"),
    (["--surface", "flat", "--speeds", "fast"], "expected START:STOP:STEP"),
    (["--surface", "iso8608:Z"], "unknown ISO 8608 class"),
    (["--surface", "flat", "--backend", "ode"], "unknown physics backend 'ode'"),
    (["--surface", "flat", "--device", "tpu"], "device must be cpu, cuda or cuda:N"),
    (["--surface", "flat", "--tire", "3 slices"], "expected SLICESxARC_RAYS"),
    (["--surface", "flat", "--length", "5"], "road length must be in [10, 5000] m"),
    ([], "give either a STAGE or --surface"),
])
def test_cli_sweep_bad_input(cli, tmp_path, args, needle):
    r = cli(*args, "-o", tmp_path / "o")
    assert r.exit_code != 0
    assert isinstance(r.exception, RoadtwinError), r.exception
    assert needle in str(r.exception) and "\n" not in str(r.exception)
    assert not (tmp_path / "o").exists()


def test_cli_sweep_bad_vehicle_file_and_stage_without_collision(cli, tmp_path):
    bad = tmp_path / "car.toml"
    bad.write_text("sprung_mass_kg = 1300.0\n")
    r = cli("--surface", "flat", "--vehicle", bad, "-o", tmp_path / "o")
    assert isinstance(r.exception, RoadtwinError) and "missing parameter(s)" in str(r.exception)
    from pxr import Usd, UsdGeom

    stage_path = tmp_path / "bare.usda"
    stage = Usd.Stage.CreateNew(str(stage_path))
    UsdGeom.SetStageUpAxis(stage, "Z")
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Town").GetPrim())
    UsdGeom.Mesh.Define(stage, "/Town/road").CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    stage.GetRootLayer().Save()
    r = cli(stage_path, "-o", tmp_path / "o")
    assert isinstance(r.exception, RoadtwinError) and "no collision mesh" in str(r.exception)


def test_backend_device_errors(pm, flat):
    run = VehicleRun(DEFAULT_CAR, np.array([[0.0, 0.0], [80.0, 0.0]]), 20.0, 5.0, 0.1)
    if HAVE_PYBULLET:
        with pytest.raises(RoadtwinError, match="CPU only"):
            pm.get("physics_backends", "pybullet").simulate(flat, [run], SimParams(device="cuda"))
    import warp as wp

    wp.init()
    if not wp.is_cuda_available():
        with pytest.raises(RoadtwinError, match="not available"):
            pm.get("physics_backends", "warp").simulate(flat, [run], SimParams(device="cuda"))
    with pytest.raises(RoadtwinError, match="dt"):
        pm.get("physics_backends", "warp").simulate(flat, [run], SimParams(dt_s=0.004))
