"""The example plugin (docs/example_plugin/) is a real package, installed the way a user would
install it: pip builds it offline with the environment's setuptools, after which the `roadtwin`
command lists it and a compose whose layout weights it places speed cushions.

The package is installed into a temporary folder (``pip install --target``) that reaches the
subprocesses through PYTHONPATH, so neither the environment nor docs/example_plugin/ is changed
(pip builds in the source folder, so it builds a copy).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import triangle
from pxr import Usd, UsdSemantics

from roadtwin_core import ComposeRules, RoadSegment, TownLayout
from roadtwin_core.usd import write_layout

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / "docs" / "example_plugin"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """A folder holding the installed example plugin (module + dist-info with its entry point)."""
    setuptools = pytest.importorskip("setuptools", reason="building the example plugin needs setuptools")
    if tuple(int(p) for p in setuptools.__version__.split(".")[:2]) < (70, 1):
        pytest.skip("the example plugin's build backend needs setuptools >= 70.1 (bdist_wheel built in)")
    base = tmp_path_factory.mktemp("example_plugin")
    source = base / "source"
    shutil.copytree(PACKAGE, source, ignore=shutil.ignore_patterns("__pycache__", "build", "*.egg-info"))
    target = base / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index",
                        "--no-cache-dir", "--disable-pip-version-check", "--quiet", "--target", str(target),
                        str(source)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"pip install of {PACKAGE} failed:\n{r.stdout}\n{r.stderr}"
    entry_points = next(target.glob("roadtwin_speed_cushion-*.dist-info")) / "entry_points.txt"
    assert "[roadtwin]" in entry_points.read_text() and "speed_cushion = roadtwin_speed_cushion" in entry_points.read_text()
    return target


def roadtwin(site: Path, *args: str) -> subprocess.CompletedProcess:
    """``python -m roadtwin_core.cli ARGS`` with the installed plugin on the path, every plugin allowed."""
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    env["PYTHONPATH"] = os.pathsep.join([str(site), *filter(None, [env.get("PYTHONPATH")])])
    env["COLUMNS"] = "200"  # one table row per plugin line
    r = subprocess.run([sys.executable, "-m", "roadtwin_core.cli", *args], cwd=REPO, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, f"roadtwin {' '.join(args)} failed ({r.returncode}):\n{r.stderr}\n{r.stdout}"
    return r


def test_roadtwin_plugins_lists_the_installed_example(site):
    out = roadtwin(site, "plugins").stdout
    rows = [line for line in out.splitlines() if line.strip("│ ").startswith("speed_cushion ")]
    assert len(rows) == 1, out
    cells = [c.strip() for c in rows[0].strip("│").split("│")]
    assert cells[1] == "0.1.0"  # the version from docs/example_plugin/pyproject.toml
    assert cells[2].startswith("defect_types: speed_cushion - Raised rectangular pad")
    assert cells[3] == ""  # no load error, the contract is met


def test_a_layout_weighting_the_example_gets_speed_cushions(site, tmp_path):
    poly = np.array([[0, 0], [30, 0], [30, 7], [0, 7]], dtype=float)
    mesh = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
    road = RoadSegment("lane", "driving", mesh["vertices"], mesh["triangles"], np.array([[0, 3.5], [30, 3.5]]))
    rules = ComposeRules(defect_count=2, seed=1, surface="flat", type_weights={"speed_cushion": 1.0},
                         models_per_type=1)
    layout = write_layout(TownLayout("Town", [road], rules), tmp_path / "road.usda")
    out = tmp_path / "out"
    roadtwin(site, "compose", str(layout), "-o", str(out), "--no-preview", "--executor", "serial")

    stage = Usd.Stage.Open(str(out / "town.usda"))
    defects = stage.GetPrimAtPath("/Town/Defects").GetChildren()
    assert defects, "no defect was placed"
    for prim in defects:
        assert prim.GetAttribute("roadtwin:defect:type").Get() == "speed_cushion"
        assert prim.GetAttribute("roadtwin:defect:heightM").Get() > 0  # a raised pad, not a hole
        labels = UsdSemantics.LabelsAPI(prim, "class").GetLabelsAttr().Get()
        assert list(labels) == ["road_defect", "speed_cushion"]
    assert (out / "library" / "speed_cushion_00.usda").exists()
