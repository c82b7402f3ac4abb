"""GroundSampler: the road height under XY points that cameras are placed on."""
import numpy as np
import triangle

from roadtwin_core.render import GroundSampler


class _Mesh:
    def __init__(self, vertices, faces):
        self.vertices, self.faces = vertices, faces


def _plane_mesh(z0: float, slope=(0.03, -0.02), seed: int = 0):
    rng = np.random.default_rng(seed)
    pts = np.vstack([[[0, 0], [40, 0], [40, 25], [0, 25]], rng.uniform([0, 0], [40, 25], (300, 2))])
    t = triangle.triangulate({"vertices": pts}, "")
    v = t["vertices"]
    z = z0 + slope[0] * v[:, 0] + slope[1] * v[:, 1]
    return np.column_stack([v, z]), t["triangles"]


def test_heights_match_the_plane_topmost_wins_and_off_mesh_is_nan():
    v1, f1 = _plane_mesh(0.0)
    v2, f2 = _plane_mesh(5.0, seed=1)
    v2 = v2 * [0.5, 0.5, 1.0]                      # a higher deck over the lower-left quarter
    mesh = _Mesh(np.vstack([v1, v2]), np.vstack([f1, f2 + len(v1)]))
    g = GroundSampler(mesh, cell_m=1.5)
    q = np.random.default_rng(2).uniform([0, 0], [40, 25], (2000, 2))
    z = g(q)
    under_deck = (q[:, 0] <= 20) & (q[:, 1] <= 12.5)
    lower = 0.03 * q[:, 0] - 0.02 * q[:, 1]
    deck = 5.0 + 0.03 * (2 * q[:, 0]) - 0.02 * (2 * q[:, 1])   # the deck's plane in its scaled coordinates
    inner = under_deck & (q[:, 0] < 19.9) & (q[:, 1] < 12.4)
    assert np.allclose(z[~under_deck], lower[~under_deck], atol=1e-9)
    assert np.allclose(z[inner], deck[inner], atol=1e-9)
    assert np.isnan(g(np.array([[-1.0, 3.0], [41.0, 3.0], [10.0, 26.0], [1e6, -1e6]]))).all()
    assert g(np.zeros((0, 2))).shape == (0,)
