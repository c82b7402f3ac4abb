"""Sweep orchestration, twin-run subtraction and recommendations with a fake physics backend
(``tests/fakes.py``): no warp, no pybullet. The expected numbers are the fake's closed form on
the test road's own depth, not the sweep code's output."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from roadtwin_core import plugins as plugins_mod
from roadtwin_core.vehicle import straight_road_scenario

from fakes import FakePhysics, fake_g, fake_plugin_manager

SPEEDS_KMH = (10.0, 40.0)
DEFECTS = ("large_deep", "small_shallow")


@pytest.fixture
def fake(monkeypatch):
    backend = FakePhysics()
    monkeypatch.setattr(plugins_mod, "_manager", fake_plugin_manager(backend))
    return backend


def run_cli(*args):
    from roadtwin_core.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_sweep_with_the_fake_backend_matches_the_closed_form(fake, tmp_path):
    out = tmp_path / "sweep"
    r = run_cli("sweep", "--surface", "flat", "--backend", "fake", "--speeds", ",".join(map(str, SPEEDS_KMH)),
                "--defects", ",".join(DEFECTS), "--no-plots", "-o", out)
    assert r.exit_code == 0, (r.output, r.exception)
    assert fake.calls == 2                                     # one batch on the road, one on its twin
    sc = straight_road_scenario(60.0, None, 0)
    depth = -sc.road.vertices[:, 2].min()
    base = -sc.baseline.vertices[:, 2].min()
    assert depth > 0.05 and abs(base) < 1e-3                    # the deep pothole is on the road only
    rows = list(csv.DictReader((out / "runs.csv").open()))
    assert sorted((r["defect"], float(r["speed_kmh"])) for r in rows) == sorted(
        (d, s) for d in DEFECTS for s in SPEEDS_KMH)
    for row in rows:
        v = float(row["speed_kmh"]) / 3.6
        expected = fake_g(depth - base, v)                     # twin-run subtraction
        assert float(row["g"]) == pytest.approx(expected, rel=1e-6), row
        assert float(row["aw"]) == pytest.approx(0.0, abs=1e-6)   # Wk removes a constant
        assert row["comfort"] == "not uncomfortable" and row["off_road"] == "False"
    # the az term dominates (g grows with v): the slowest speed is best by far
    g = {float(r["speed_kmh"]): float(r["g"]) for r in rows if r["defect"] == DEFECTS[0]}
    assert g[40.0] > 1.25 * g[10.0]
    recs = json.loads((out / "recommendations.json").read_text())
    assert {r["defect"] for r in recs} == set(DEFECTS)
    for rec in recs:
        assert rec["recommended_speed_kmh"] == 10.0 and rec["speed_of_g_max_kmh"] == 40.0
        assert rec["note"] == "g is highest at the top speed: slow down"
        assert rec["max_comfortable_speed_kmh"] == 40.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["backend"] == "fake" and summary["runs"] == 4
    npz = np.load(out / "traces.npz")
    assert npz["acc"].shape[0] == 4


def test_recommendation_follows_g_when_it_falls_with_speed(fake, tmp_path, monkeypatch):
    """With the roll term dominant, g falls as 1/v: the top speed is recommended."""
    import fakes

    monkeypatch.setattr(fakes, "K_AZ", 0.0)
    out = tmp_path / "sweep"
    r = run_cli("sweep", "--surface", "flat", "--backend", "fake", "--speeds", "10,40", "--defects", DEFECTS[0],
                "--no-plots", "-o", out)
    assert r.exit_code == 0, (r.output, r.exception)
    rows = {float(r["speed_kmh"]): float(r["g"]) for r in csv.DictReader((out / "runs.csv").open())}
    assert rows[10.0] / rows[40.0] == pytest.approx(4.0, rel=1e-6)    # g ~ 1/v
    (rec,) = json.loads((out / "recommendations.json").read_text())
    assert rec["recommended_speed_kmh"] == 40.0
    assert rec["note"] == "g is highest at the lowest speed: a higher speed reduces it"
