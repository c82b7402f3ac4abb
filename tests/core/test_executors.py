"""Per-segment work gives the same bytes whichever executor runs it (issue: local vs Ray)."""
from __future__ import annotations

import numpy as np
import pytest
import triangle

from roadtwin_core import ComposeRules, RoadSegment, RoadtwinError, TownLayout
from roadtwin_core.apps.compose.run import compose
from roadtwin_core.executors import LocalExecutor, SerialExecutor, make_executor
from roadtwin_core.usd import write_layout

LAYERS = ["town.usda", "layers/roads.usda", "layers/defects.usda", "layers/physics.usda", "layers/semantics.usda",
          "layers/roads.geom.usdc", "layers/defects.geom.usdc"]


def _strip(x0: float, x1: float, y0: float, y1: float, name: str) -> RoadSegment:
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
    return RoadSegment(name, "driving", t["vertices"], t["triangles"], np.array([[x0, (y0 + y1) / 2], [x1, (y0 + y1) / 2]]))


@pytest.fixture(scope="module")
def small_layout(tmp_path_factory):
    segs = [_strip(x, x + 10, y, y + 3.5, f"s{i}_{j}") for i, x in enumerate((0.0, 10.0, 20.0))
            for j, y in enumerate((0.0, 3.5))]
    rules = ComposeRules(defect_count=12, seed=3, surface="iso8608:C:0.1", models_per_type=2)
    path = tmp_path_factory.mktemp("layout") / "small.usda"
    write_layout(TownLayout("Town", segs, rules), path)
    return path


def _square(context, item):
    return context * item * item


def test_executors_keep_item_order():
    items = list(range(23))
    expected = [2 * i * i for i in items]
    assert SerialExecutor().map(_square, 2, items) == expected
    assert LocalExecutor(2).map(_square, 2, items) == expected


def test_unknown_executor_is_refused():
    with pytest.raises(RoadtwinError, match="unknown executor 'dask'"):
        make_executor("dask")


def test_serial_local_and_ray_compose_identical_bytes(small_layout, tmp_path):
    pytest.importorskip("ray")
    outs = {}
    for name in ("serial", "local", "ray"):
        out = tmp_path / name
        compose(small_layout, out, executor=name, workers=2, preview=False)
        outs[name] = {f: (out / f).read_bytes() for f in LAYERS}
    assert outs["serial"]["layers/defects.usda"].count(b"def Mesh") > 0
    for name in ("local", "ray"):
        for f in LAYERS:
            assert outs[name][f] == outs["serial"][f], f"{name}: {f} differs from the serial compose"
