"""One straight 30 m x 7 m driving lane as a layout file: the small town the library, decal and
photo-surface tests compose (importable from every test folder: tests/conftest.py)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import triangle

from roadtwin_core import ComposeRules, RoadSegment, TownLayout
from roadtwin_core.usd import write_layout


def write_lane_layout(path: Path, defect_count: int, seed: int, defect_type: str = "pothole") -> Path:
    """The lane, flat, ``defect_count`` defects of ``defect_type`` (one model of it), written to ``path``."""
    poly = np.array([[0, 0], [30, 0], [30, 7], [0, 7]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
    seg = RoadSegment("lane", "driving", t["vertices"], t["triangles"], np.array([[0, 3.5], [30, 3.5]]))
    write_layout(TownLayout("Town", [seg], ComposeRules(defect_count=defect_count, seed=seed, surface="flat",
                                                          type_weights={defect_type: 1.0}, models_per_type=1)), path)
    return path
