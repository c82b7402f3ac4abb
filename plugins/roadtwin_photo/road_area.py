"""Where a photo shows plain road: the clean area of a labelled frame on an ortho grid, and the
largest clean square in it (core-free: numpy + OpenCV).

A texel of the road plane is *clean* when it is

- inside the image, at least ``border_px`` pixels from its edge;
- labelled road (a road class of the class map: for ``road_defects_br`` the ego lane);
- at least ``defect_margin_m`` from every labelled defect pixel (crack, pothole: labels are
  drawn loosely, and a crack's halo of ravelling is not plain road either);
- at least ``paint_margin_m`` from lane paint and from anything that is not asphalt. Both are
  told by colour against the frame's own road (CIELAB): paint is much lighter than the frame's
  median road (white) or strongly coloured (yellow); strongly coloured is also the red soil and
  grass an ego-lane label sweeps in at its wide bottom;
- seen well: the worst-direction ground size of one photo pixel there is at most ``max_gsd_m``
  (a forward camera's pixels stretch along the road with range: this is the range band).

Everything is measured on the road in metres, so the margins mean the same at every range.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rectify import OrthoGrid, PhotoRig


@dataclass(frozen=True)
class CleanParams:
    search_texel_m: float = 0.02     # the grid the clean area is found on
    max_gsd_m: float = 0.03          # worst-direction metres per photo pixel
    border_px: int = 8
    defect_margin_m: float = 0.25
    paint_margin_m: float = 0.15
    paint_lightness: float = 45.0    # L* (0..255 scale of OpenCV's 8-bit Lab) above the road's median
    max_chroma: float = 22.0         # sqrt(a*^2 + b*^2) (8-bit Lab) above which a pixel is not asphalt
    reach_m: float = 12.0            # the search grid's extent ahead of the camera
    half_width_m: float = 4.0        # ... and to each side


def ground_sample_m(rig: PhotoRig, grid: OrthoGrid, width: int, height: int) -> np.ndarray:
    """(rows, cols) worst-direction road metres per photo pixel at each texel centre: the
    inverse of the smallest singular value of the road -> pixel Jacobian (finite differences of
    the rig's homography; a 2x2 matrix's singular values from its Frobenius norm and determinant)."""
    x, y = grid.centres()
    xy = np.column_stack([x.ravel(), y.ravel()])
    e = 1e-3
    p0, z = rig.project(xy, width, height)
    du = (rig.project(xy + [e, 0.0], width, height)[0] - p0) / e
    dv = (rig.project(xy + [0.0, e], width, height)[0] - p0) / e
    frob = (du ** 2).sum(1) + (dv ** 2).sum(1)
    det = du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]
    smallest_sq = 0.5 * (frob - np.sqrt(np.maximum(frob ** 2 - 4 * det ** 2, 0.0)))
    with np.errstate(divide="ignore", invalid="ignore"):
        gsd = np.where((z > 0) & (smallest_sq > 0), 1.0 / np.sqrt(smallest_sq), np.inf)
    return gsd.reshape(grid.rows, grid.cols)


@dataclass
class SearchView:
    """The search grid of one rig and image size, its remap tables and where it sees well:
    the same for every frame of that size, so made once."""

    grid: OrthoGrid
    map_u: np.ndarray
    map_v: np.ndarray
    well_seen: np.ndarray        # (rows, cols) bool: inside the image (minus the border), gsd <= max_gsd_m
    gsd: np.ndarray              # (rows, cols) worst-direction road metres per photo pixel

    def ortho(self, mask: np.ndarray) -> np.ndarray:
        import cv2

        return cv2.remap(mask.astype(np.uint8), self.map_u, self.map_v, cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)


def search_view(rig: PhotoRig, width: int, height: int, p: CleanParams) -> SearchView:
    rows, cols = int(p.reach_m / p.search_texel_m), int(2 * p.half_width_m / p.search_texel_m)
    grid = OrthoGrid(p.reach_m, p.half_width_m, p.search_texel_m, rows, cols)
    x, y = grid.centres()
    uv, z = rig.project(np.column_stack([x.ravel(), y.ravel()]), width, height)
    uv[z <= 0] = -1e6
    map_u = uv[:, 0].reshape(rows, cols).astype(np.float32)
    map_v = uv[:, 1].reshape(rows, cols).astype(np.float32)
    b = p.border_px
    inside = (map_u >= b) & (map_u <= width - 1 - b) & (map_v >= b) & (map_v <= height - 1 - b)
    gsd = ground_sample_m(rig, grid, width, height)
    return SearchView(grid, map_u, map_v, inside & (gsd <= p.max_gsd_m), gsd)


def paint_or_not_asphalt(rgb: np.ndarray, road: np.ndarray, p: CleanParams) -> np.ndarray:
    """(H, W) bool: lane paint (much lighter than the frame's median road) or not asphalt
    (strongly coloured: yellow paint, soil, grass), specks of one or two pixels dropped."""
    import cv2

    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    lightness = lab[..., 0]
    chroma = np.hypot(lab[..., 1] - 128.0, lab[..., 2] - 128.0)
    median = float(np.median(lightness[road])) if road.any() else float(np.median(lightness))
    odd = (lightness > median + p.paint_lightness) | (chroma > p.max_chroma)
    return cv2.morphologyEx(odd.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)


def clean_area(rgb: np.ndarray, label: np.ndarray, road_ids, defect_ids, view: SearchView,
               p: CleanParams) -> np.ndarray:
    """(rows, cols) bool: the clean texels of ``view``'s grid (module docstring)."""
    import cv2

    road = np.isin(label, list(road_ids))
    defect = np.isin(label, list(defect_ids))
    odd = paint_or_not_asphalt(rgb, road & ~defect, p)

    def far_from(mask: np.ndarray, margin_m: float) -> np.ndarray:
        free = (~mask).astype(np.uint8)
        return cv2.distanceTransform(free, cv2.DIST_L2, 5) * p.search_texel_m > margin_m

    road_t = view.ortho(road)
    clean = view.well_seen & road_t & far_from(view.ortho(defect), p.defect_margin_m)
    # the lane's own edges count as paint: its lines lie along them
    return clean & far_from(view.ortho(odd & road) | ~road_t, p.paint_margin_m)


def largest_square(clean: np.ndarray) -> tuple[int, int, int]:
    """(side, row0, col0) of the largest all-clean axis-aligned square (texels); among equals
    the one nearest the bottom of the grid (nearest the camera, sharpest), then leftmost."""
    import cv2

    padded = np.pad(clean.astype(np.uint8), 1)                        # the grid's edge is not clean
    # chessboard distance to the nearest unclean texel: a (2d - 1)-texel square centred here fits
    d = cv2.distanceTransform(padded, cv2.DIST_C, 3)[1:-1, 1:-1].astype(int)
    best = int(d.max())
    if best <= 0:
        return 0, 0, 0
    rr, cc = np.nonzero(d == best)
    k = int(np.lexsort((cc, -rr))[0])
    side = 2 * best - 1
    return side, int(rr[k]) - best + 1, int(cc[k]) - best + 1


def square_at(clean: np.ndarray, side: int) -> tuple[int, int] | None:
    """(row0, col0) of an all-clean ``side`` square nearest the bottom, then leftmost (an
    integral image: exact for any side, not only odd ones)."""
    if side <= 0 or side > min(clean.shape):
        return None
    ii = np.pad(clean.astype(np.int64), ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    full = ii[side:, side:] - ii[:-side, side:] - ii[side:, :-side] + ii[:-side, :-side]
    rr, cc = np.nonzero(full == side * side)
    if not len(rr):
        return None
    k = int(np.lexsort((cc, -rr))[0])
    return int(rr[k]), int(cc[k])


def axis_samples_m(rig: PhotoRig, grid: OrthoGrid, width: int, height: int) -> tuple[float, float]:
    """The coarsest road metres per photo pixel over ``grid`` along travel (x) and across it (y):
    1 / |d pixel / d x| and 1 / |d pixel / d y| at an 8 x 8 lattice over the grid."""
    coarse = OrthoGrid(grid.x_max, grid.y_max, grid.texel * max(grid.rows, grid.cols) / 8, 8, 8)
    x, y = coarse.centres()
    xy = np.column_stack([x.ravel(), y.ravel()])
    e = 1e-3
    p0, _ = rig.project(xy, width, height)
    along = e / np.linalg.norm(rig.project(xy + [e, 0.0], width, height)[0] - p0, axis=1)
    across = e / np.linalg.norm(rig.project(xy + [0.0, e], width, height)[0] - p0, axis=1)
    return float(along.max()), float(across.max())


def uniform_resolution(ortho: np.ndarray, texel_m: float, along_m: float, across_m: float) -> np.ndarray:
    """An ortho patch (rows along travel) brought to one resolution everywhere: area-averaged
    down to the coarsest photo sample along and across travel, then cubic back to its texels.
    A forward camera sees the near end of a window two or three times sharper than the far
    end; repeated, that change of sharpness would mark every repeat."""
    import cv2

    rows, cols = ortho.shape[:2]
    small = (max(2, round(cols * texel_m / across_m)), max(2, round(rows * texel_m / along_m)))
    if small[0] >= cols and small[1] >= rows:
        return ortho
    down = cv2.resize(ortho, small, interpolation=cv2.INTER_AREA)
    return cv2.resize(down, (cols, rows), interpolation=cv2.INTER_CUBIC)
