"""The drive's LiDAR ray caster (``apps/drive/world.py``): open3d's on the CPU, warp's where open3d
is missing or on CUDA (the GPU machine). Both against the closed form: rays from a known point to
a square of road at z = 0 with a pothole-class triangle pair beside it."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from roadtwin_core.apps.drive.world import World, _warp_caster
from roadtwin_core.render import RenderParams


def square_world() -> World:
    """x in [-10, 0): road (class 1), x in [0, 10]: pothole (class 2, defect instance 7)."""
    v = np.array([[-10, -10, 0], [0, -10, 0], [0, 10, 0], [-10, 10, 0], [10, -10, 0], [10, 10, 0]], float) + [500, 300, 4]
    f = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    mesh = SimpleNamespace(vertices=v, faces=f, classes=["background", "road", "pothole"], instances=[],
                           face_class=np.array([1, 1, 2, 2]), face_instance=np.array([0, 0, 7, 7]))
    return World(mesh, None, RenderParams())


@pytest.mark.parametrize("caster", ["open3d", "warp"])
def test_lidar_rays_hit_the_road_at_the_closed_form_range(caster):
    pytest.importorskip(caster)
    world = square_world()
    if caster == "warp":
        world._rays = _warp_caster(np.ascontiguousarray(world.mesh.vertices - world.origin, np.float32),
                                   world.mesh.faces.astype(np.int32), "cpu")
    rng = np.random.default_rng(0)
    origin = np.array([500.0, 300.0, 6.0])                       # 2 m above the road
    dirs = np.column_stack([rng.uniform(-1, 1, (200, 2)), -np.ones(200)])
    dirs[:5] = [[0, 0, 1], [3, 0, -0.1], [-0.5, 0.2, -1], [0.5, -0.2, -1], [20, 0, -1]]   # up, off the square
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hit = world.cast(np.tile(origin, (200, 1)), dirs)
    t_true = 2.0 / -dirs[:, 2]
    x_true = dirs[:, 0] * t_true
    on = (dirs[:, 2] < 0) & (np.abs(x_true) <= 10) & (np.abs(dirs[:, 1] * t_true) <= 10)
    assert not on[[0, 1, 4]].any() and on[[2, 3]].all()
    assert np.all(np.isinf(hit["t"][~on])) and np.all(hit["class_id"][~on] == 0)
    np.testing.assert_allclose(hit["t"][on], t_true[on], rtol=1e-5)
    np.testing.assert_array_equal(hit["class_id"][on], np.where(x_true[on] < 0, 1, 2))
    np.testing.assert_array_equal(hit["instance"][on], np.where(x_true[on] < 0, 0, 7))
