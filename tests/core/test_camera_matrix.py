"""``roadtwin_core.render.camera_matrix``: the one reader of a camera matrix K that the LiDAR and
stereo reconstructors share (a calibration file's fx, fy, cx, cy or nine entries)."""
from __future__ import annotations

import numpy as np
import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.render import Intrinsics, camera_matrix


def test_four_numbers_and_nine_give_the_pinhole_matrix():
    k = Intrinsics.from_fov(640, 480, 90.0)
    expected = np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1.0]])
    assert np.array_equal(camera_matrix((k.fx, k.fy, k.cx, k.cy)), expected)
    assert np.array_equal(camera_matrix(expected.tolist()), expected)
    # a point on the optical axis 2 m ahead lands on the principal point
    uvw = camera_matrix((k.fx, k.fy, k.cx, k.cy)) @ np.array([0.0, 0.0, 2.0])
    assert uvw[:2] / uvw[2] == pytest.approx((k.cx, k.cy))


@pytest.mark.parametrize("bad", [(500.0, 500.0, 320.0), (0.0, 500.0, 320.0, 240.0), (500.0, -1.0, 320.0, 240.0),
                                 (500.0, float("nan"), 320.0, 240.0), "five hundred", [[1, 2], [3]]])
def test_anything_else_is_one_line_naming_the_input(bad):
    with pytest.raises(RoadtwinError) as e:
        camera_matrix(bad, "calib.txt: K")
    assert str(e.value).startswith("calib.txt: K: ") and "\n" not in str(e.value)
