"""preview.png pieces: the camera spot (lane point facing the most defects 5-20 m ahead) and the
rasterized top-down map, checked against hand-made lanes and geometry. The preview of a composed
town (render + map, and the map alone without a renderer) is tested in test_render.py, which
composes a town once."""
from __future__ import annotations

import math

import numpy as np

from roadtwin_core.apps.compose.preview import choose_spot, fill_triangles, rasterize_map
from roadtwin_core.render import Lane, RenderMesh, class_names


def test_spot_faces_the_defect_cluster():
    defects = np.array([[60.0, 0.3], [61.0, -1.0], [63.0, 1.5], [20.0, 0.0], [60.0, 30.0]])
    forward = Lane("east", np.array([[0.0, 0.0], [100.0, 0.0]]))
    spot = choose_spot([forward], defects)
    # all three clustered defects (x 60-63) lie 5-20 m ahead only for x in [43, 55]; the
    # mid-window tie-break puts their mean (61.3 m) 12.5 m ahead
    assert spot.defects_ahead == 3 and spot.lane == "east" and spot.heading == 0.0
    assert 43.0 <= spot.xy[0] <= 55.0 and abs(spot.xy[0] - (61.33 - 12.5)) <= 1.0
    backward = Lane("west", np.array([[100.0, 0.0], [0.0, 0.0]]))
    spot = choose_spot([backward], defects)
    assert spot.defects_ahead == 3 and abs(abs(spot.heading) - math.pi) < 1e-9
    assert 68.0 <= spot.xy[0] <= 80.0
    # a lane that sees more wins over an earlier one that sees fewer
    spot = choose_spot([Lane("far", np.array([[0.0, 30.0], [100.0, 30.0]])), forward], defects)
    assert spot.lane == "east"
    assert choose_spot([], defects) is None
    assert choose_spot([forward], np.zeros((0, 2))).defects_ahead == 0


def test_fill_triangles_covers_what_the_triangles_cover():
    """Pixel centres inside the triangles are painted, those outside are not (every size class
    of the rasterizer), checked against a point-in-triangle test done here."""
    rng = np.random.default_rng(0)
    h, w = 60, 80
    tris = []
    for size in (0.6, 1.5, 2.5, 3.5, 12.0):              # every code path
        c = rng.uniform(5, 55, size=(40, 1, 2)) * [w / 60, 1.0]
        tris.append(c + rng.normal(scale=size / 2, size=(40, 3, 2)))
    t = np.concatenate(tris).astype(np.float32)
    img = np.zeros((h, w, 3), np.uint8)
    fill_triangles(img, t[:, 0], t[:, 1], t[:, 2], (255, 255, 255))
    painted = img[..., 0] > 0
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    q = np.stack([u, v], -1).reshape(-1, 1, 2)
    a, b, c = t[None, :, 0], t[None, :, 1], t[None, :, 2]

    def cross(p0, p1):
        return (p1[..., 0] - p0[..., 0]) * (q[..., 1] - p0[..., 1]) - (p1[..., 1] - p0[..., 1]) * (q[..., 0] - p0[..., 0])

    e = np.stack([cross(a, b), cross(b, c), cross(c, a)])
    inside = ((e >= 0).all(0) | (e <= 0).all(0)).any(axis=1).reshape(h, w)
    assert inside.sum() > 500
    assert (painted | ~inside).all()
    extra = painted & ~inside
    tiny = (np.maximum(np.maximum(t[:, 0], t[:, 1]), t[:, 2]) - np.minimum(np.minimum(t[:, 0], t[:, 1]), t[:, 2])).max(1) < 2
    assert extra.sum() <= tiny.sum()           # at most the centroid pixel of each sub-pixel triangle


def test_map_colours_roads_defects_and_markings():
    # a 40 x 20 m road of 1 m strips at z = 0..2 (sloped along x), a 2 m disc "defect" of tiny triangles, a
    # 0.3 m wide marking strip along y = -5
    xs = np.arange(41.0)
    road_v = np.vstack([np.column_stack([xs, np.full(41, -10.0), xs / 20]), np.column_stack([xs, np.full(41, 10.0), xs / 20])])
    road_f = np.vstack([[[i, i + 1, 42 + i], [i, 42 + i, 41 + i]] for i in range(40)])
    n = 400
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    disc_v = np.vstack([[10, 0, 0.5], np.column_stack([10 + np.cos(ang), np.sin(ang), np.full(n, 0.5)])])
    disc_f = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    mark_v = np.array([[2, -5.15, 0.1], [38, -5.15, 1.9], [38, -4.85, 1.9], [2, -4.85, 0.1]], float)
    classes = class_names(["pothole"])
    v = np.vstack([road_v, disc_v, mark_v])
    mark_f = np.array([[0, 1, 2], [0, 2, 3]])
    f = np.vstack([road_f, disc_f + len(road_v), mark_f + len(road_v) + len(disc_v)])
    m = len(f)
    cls = np.r_[[classes.index("driving")] * 80, [classes.index("pothole")] * n, [classes.index("lane_marking")] * 2]
    inst = np.r_[[0] * 80, [1] * n, [0] * 2]
    mesh = RenderMesh(v, f, cls, inst, np.zeros(m), np.zeros((m, 3, 2)), classes)
    img, extent, (zlo, zhi) = rasterize_map(mesh, width_px=420)      # 10 px per metre
    np.testing.assert_allclose((zlo, zhi), (1 / 60, 2 - 1 / 60))      # face means of the end strips
    px_per_m = 420 / (extent[1] - extent[0])
    red = (img[..., 0] == 200) & (img[..., 1] == 20)
    assert abs(red.sum() - math.pi * px_per_m ** 2) < 0.1 * math.pi * px_per_m ** 2
    white = (img == 255).all(-1)
    # the strip is 3 px wide and 360 px long; the background is the 1 m margin around the town
    top = int(round((extent[3] - 10) * px_per_m))               # the road's rows: y from 10 to -10 m
    strip = white[top:top + int(20 * px_per_m), int(5 * px_per_m):int(35 * px_per_m)]
    rows = top + np.flatnonzero(strip.mean(axis=1) > 0.9)
    assert len(rows) in (2, 3, 4) and np.ptp(rows) <= 3
    y_mid = (extent[3] - (rows.mean() + 0.5) / px_per_m)
    assert abs(y_mid + 5.0) < 0.15
    # elevation bands: the road's colour changes along x (the slope) but not along y
    row = img[int(2 * px_per_m), int(2 * px_per_m):int(38 * px_per_m)].astype(int)
    col = img[int(3 * px_per_m):int(8 * px_per_m), int(30 * px_per_m)].astype(int)
    assert np.abs(np.diff(row, axis=0)).sum() > 100 and np.abs(np.diff(col, axis=0)).sum() == 0
