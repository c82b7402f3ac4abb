"""The vectorised helpers behind the merge's speed give what the plain versions give."""
from __future__ import annotations

import numpy as np
import pytest

from roadtwin_cdt.merger import _may_enclose
from roadtwin_core import SampledSurface
from roadtwin_core.geometry import boundary_edges, subdivide_edge, subdivide_ring


@pytest.mark.parametrize("seed", range(5))
def test_subdivide_ring_is_the_edges_subdivided_one_by_one(seed):
    """Bit for bit the points of subdivide_edge (the watertight border depends on it), with
    edges in both directions, vertical ones and edges shorter than the spacing."""
    rng = np.random.default_rng(seed)
    loop = rng.uniform(-40, 40, (12, 2))
    loop[3, 0] = loop[2, 0]                      # vertical edge (x ties, flip decided by y)
    loop[7] = loop[6] + [0.1, 0.05]              # shorter than the spacing: no inner points
    spacing = 0.7
    want = np.concatenate([np.concatenate([loop[i][None], subdivide_edge(loop[i], loop[(i + 1) % 12], spacing)])
                           for i in range(12)])
    got = subdivide_ring(loop, spacing)
    assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_level_samples_give_their_level():
    xy = np.random.default_rng(1).uniform(0, 50, (300, 2))
    s = SampledSurface(np.c_[xy, np.full(300, 2.25)])
    q = np.random.default_rng(2).uniform(-10, 60, (100, 2))
    assert (s.height(q) == 2.25).all()


def _grid_faces(n: int) -> np.ndarray:
    """Two triangles per cell of an n x n grid of cells; vertex id = i * (n + 1) + j."""
    f = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = i * (n + 1) + j, i * (n + 1) + j + 1, (i + 1) * (n + 1) + j + 1, (i + 1) * (n + 1) + j
            f += [[a, b, c], [a, c, d]]
    return np.array(f)


def _cells(n: int, cells: list[tuple[int, int]]) -> np.ndarray:
    faces = _grid_faces(n)
    return np.concatenate([faces[2 * (i * n + j): 2 * (i * n + j) + 2] for i, j in cells])


@pytest.mark.parametrize("cells, encloses", [
    ([(1, 1)], False),                                                   # one disk
    ([(0, 0), (0, 1), (3, 3)], False),                                   # two disjoint disks
    ([(i, j) for i in range(3) for j in range(3) if (i, j) != (1, 1)], True),   # annulus
    ([(i, j) for i in range(3) for j in range(3) if (i, j) != (1, 1)] + [(4, 4)], True),
    ([(0, 0), (1, 1)], True),                                            # pinched at a vertex
])
def test_may_enclose_counts_regions_against_loops(cells, encloses):
    faces = _cells(5, cells)
    assert _may_enclose(faces, boundary_edges(faces)) is encloses
