"""The CDT merger's ring refinement is bounded (``roadtwin_cdt.merger.refine``).

The degenerate ring is real: the ring Triangle was refining when a highway compose with crack
footprints traced from ``road_defects_br`` train photos grew past 4 GB here (60 GB on the GPU
machine). One of its loops has a vertex lying on its own next segment: a zero input angle, where
Ruppert's refinement never ends (``tests/data/degenerate_crack_ring.npz``: vertices, segments,
hole seeds).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

triangle = pytest.importorskip("triangle")
merger = pytest.importorskip("roadtwin_cdt.merger")

RING = Path(__file__).resolve().parents[1] / "data" / "degenerate_crack_ring.npz"


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def area(out: dict) -> float:
    p = out["vertices"][out["triangles"]]
    return float(0.5 * np.abs(cross2(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])).sum())


def test_a_zero_angle_loop_stops_at_the_bound_and_the_ring_keeps_its_unsplit_fill():
    d = np.load(RING)
    tri_in = {"vertices": d["vertices"], "segments": d["segments"], "holes": d["holes"]}
    n = len(tri_in["vertices"])
    bound = merger.STEINER_PER_VERTEX * n + 1000
    assert len(triangle.triangulate(tri_in, f"pq20.5S{bound}")["vertices"]) == n + bound   # no end but the bound
    assert merger.refine(tri_in, "pq20.5") is None
    out = merger.refine(tri_in, "pq20.5YY")              # the fill the merger keeps: segments not split
    np.testing.assert_array_equal(out["vertices"][:n], tri_in["vertices"])
    p = out["vertices"][out["triangles"]]
    assert (np.abs(cross2(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])) > 0).all()
    assert area(out) == pytest.approx(area(triangle.triangulate(tri_in, "p")), rel=1e-9)   # the same region, filled


def test_a_normal_ring_is_refined_as_without_the_bound():
    outer = [(0, 0), (6, 0), (6, 4), (0, 4)]
    loop = [(2, 1.5), (3.5, 1.2), (4, 2.5), (2.5, 2.8)]
    v = np.array(outer + loop, float)
    seg = [(i, (i + 1) % 4) for i in range(4)] + [(4 + i, 4 + (i + 1) % 4) for i in range(4)]
    tri_in = {"vertices": v, "segments": np.array(seg), "holes": np.array([[3.0, 2.0]])}
    for switches in ("pq20.5YY", "pq20.5"):
        a, b = merger.refine(tri_in, switches), triangle.triangulate(tri_in, switches)
        np.testing.assert_array_equal(a["vertices"], b["vertices"])
        np.testing.assert_array_equal(a["triangles"], b["triangles"])
