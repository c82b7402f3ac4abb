"""The batched ray tests answer exactly what the full (ray x triangle) matrix answers.

The merger's cut and the markings' draping use :func:`vertical_ray_hits_pairs` /
:func:`first_vertical_hits` for speed; outputs must stay byte-identical, so the reference here
is the plain matrix form (:func:`vertical_ray_hits`) and ``np.unique`` on rows.
"""
import numpy as np

from roadtwin_cdt.merger import _first_equal_row
from roadtwin_core.geometry import first_vertical_hits, vertical_ray_hits, vertical_ray_hits_pairs


def _mesh(rng, n=300):
    """A grid triangulation (rays on shared edges and vertices: the tie cases) plus loose
    random triangles (overlaps, slivers) with heights."""
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), -1).reshape(-1, 2)
    quads = [(i * 6 + j, i * 6 + j + 1, (i + 1) * 6 + j, (i + 1) * 6 + j + 1) for i in range(5) for j in range(5)]
    grid = np.array([g[[a, b, d]] for a, b, c, d in quads] + [g[[a, d, c]] for a, b, c, d in quads])
    loose = rng.uniform(0, 5, (n, 3, 2))
    tri2 = np.concatenate([grid, loose])
    return np.concatenate([tri2, rng.normal(0, 0.1, (len(tri2), 3, 1))], axis=2)


def test_pairs_match_the_matrix_on_edges_vertices_and_random_points():
    rng = np.random.default_rng(4)
    tri = _mesh(rng)
    pts = np.concatenate([rng.uniform(-0.5, 5.5, (400, 2)), np.stack(np.meshgrid(np.arange(0, 5.5, 0.5),
                          np.arange(0, 5.5, 0.5)), -1).reshape(-1, 2)])
    full = vertical_ray_hits(pts, tri)
    pp, pt = np.repeat(np.arange(len(pts)), len(tri)), np.tile(np.arange(len(tri)), len(pts))
    pairs = vertical_ray_hits_pairs(pts, tri, pp, pt)
    assert full.sum() > len(pts)                       # many rays hit several triangles
    assert np.array_equal(pairs.reshape(len(pts), len(tri)), full)
    first = first_vertical_hits(pts, tri)
    assert np.array_equal(first, np.where(full.any(axis=1), full.argmax(axis=1), -1))


def test_first_equal_row_matches_numpy_unique():
    rng = np.random.default_rng(1)
    xy = rng.integers(0, 5, (500, 2)).astype(float) * 0.1
    xy[::7, 0] = -0.0                                   # -0.0 and 0.0 are one point
    _, first, inverse = np.unique(xy, axis=0, return_index=True, return_inverse=True)
    assert np.array_equal(_first_equal_row(xy), first[inverse.ravel()])
