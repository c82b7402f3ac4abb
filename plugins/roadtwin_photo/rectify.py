"""Photo pixels <-> the flat road plane through a known camera rig (core-free: numpy + OpenCV).

Frames (as everywhere in roadtwin): the road is the plane z = 0 of a Z-up world in metres; the
camera stands at (0, 0, height_m) looking along +x (yaw 0), pitched by ``pitch_deg`` (negative
looks down) and rolled by ``roll_deg``; camera axes are OpenCV's (x right, y down, z forward) and
pixel centres sit at integer coordinates, so a W x H image has its principal point at
((W - 1) / 2, (H - 1) / 2).

A rig is given at a reference image size (the survey preset: 512x320, the size its height and
pitch were estimated at); a photo of another size W x H is taken as the same view resampled, so
``fx`` scales with ``W / width`` and ``fy`` with ``H / height`` (the 1024x630 train frames are
anisotropic by 1.6 %, which is how the 512x320 copies were made from them).

A ground point (x, y, 0) maps to a pixel by the homography ``H = K [r1' r2' -R'C]`` (``R'`` the
world-to-camera rotation, ``C`` the camera centre), so ortho-rectifying a photo is one
``cv2.remap`` through ``H`` on a metric grid: no ray casting, exact for a flat road.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PhotoRig:
    """A mono camera above a flat road, intrinsics given at a reference image size."""

    name: str
    width: int
    height: int
    hfov_deg: float
    height_m: float
    pitch_deg: float
    roll_deg: float = 0.0
    max_range_m: float = 80.0     # a labelled pixel whose ray meets the road farther away "misses" it

    def describe(self) -> str:
        return (f"rig {self.name} (height {self.height_m:g} m, pitch {self.pitch_deg:g} deg, roll {self.roll_deg:g} deg, "
                f"hfov {self.hfov_deg:g} deg at {self.width}x{self.height})")

    def K(self, width: int, height: int) -> np.ndarray:
        f = 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2)
        fx, fy = f * width / self.width, f * height / self.height
        return np.array([[fx, 0, (width - 1) / 2.0], [0, fy, (height - 1) / 2.0], [0, 0, 1.0]])

    def rotation(self) -> np.ndarray:
        """Camera-to-world rotation (columns: camera x right, y down, z forward), as
        ``roadtwin_core.render.rotation_ypr(0, pitch, roll)``."""
        pitch, roll = math.radians(self.pitch_deg), math.radians(self.roll_deg)
        f = np.array([math.cos(pitch), 0.0, math.sin(pitch)])
        r = np.array([0.0, -1.0, 0.0])
        d = np.cross(f, r)
        c, s = math.cos(roll), math.sin(roll)
        r, d = c * r + s * d, -s * r + c * d
        return np.column_stack([r, d, f])

    def centre(self) -> np.ndarray:
        return np.array([0.0, 0.0, self.height_m])

    def ground_to_pixel(self, width: int, height: int) -> np.ndarray:
        """3x3 homography: (x, y, 1) on the road -> homogeneous pixel."""
        rt = self.rotation().T
        return self.K(width, height) @ np.column_stack([rt[:, 0], rt[:, 1], -rt @ self.centre()])

    def pixel_rays(self, u: np.ndarray, v: np.ndarray, width: int, height: int) -> np.ndarray:
        """World ray directions (N, 3) (not normalized) of pixel coordinates."""
        k = self.K(width, height)
        dc = np.stack([(np.asarray(u, float) - k[0, 2]) / k[0, 0], (np.asarray(v, float) - k[1, 2]) / k[1, 1],
                       np.ones(np.shape(u))], axis=-1)
        return dc @ self.rotation().T

    def backproject(self, u: np.ndarray, v: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Pixels -> road points (N, 2) and a mask of the pixels whose ray meets the road
        within ``max_range_m`` (the others get NaN)."""
        d = self.pixel_rays(u, v, width, height)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -self.height_m / d[:, 2]
        xy = t[:, None] * d[:, :2]
        ok = (d[:, 2] < -1e-9) & np.isfinite(t) & (np.hypot(xy[:, 0], xy[:, 1]) <= self.max_range_m)
        xy[~ok] = np.nan
        return xy, ok

    def project(self, xy: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Road points (N, 2) -> pixel coordinates (N, 2) and camera depth (N,)."""
        h = self.ground_to_pixel(width, height)
        p = np.column_stack([xy, np.ones(len(xy))]) @ h.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return p[:, :2] / p[:, 2:3], p[:, 2]


@dataclass
class OrthoGrid:
    """A metric grid on the road: row i is x = x_max - (i + 0.5) texel (forward up), column j
    is y = y_max - (j + 0.5) texel (left on the left), as a top view seen with travel upwards."""

    x_max: float
    y_max: float
    texel: float
    rows: int
    cols: int

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        x = self.x_max - (np.arange(self.rows) + 0.5) * self.texel
        y = self.y_max - (np.arange(self.cols) + 0.5) * self.texel
        return np.meshgrid(x, y, indexing="ij")

    def to_rc(self, xy: np.ndarray) -> np.ndarray:
        """Road points -> fractional (row, col) of texel centres."""
        return np.column_stack([(self.x_max - xy[:, 0]) / self.texel - 0.5, (self.y_max - xy[:, 1]) / self.texel - 0.5])

    def to_xy(self, rc: np.ndarray) -> np.ndarray:
        return np.column_stack([self.x_max - (rc[:, 0] + 0.5) * self.texel, self.y_max - (rc[:, 1] + 0.5) * self.texel])


def grid_around(xy: np.ndarray, texel: float, margin: float, max_texels: int) -> OrthoGrid:
    """The grid covering ``xy`` plus ``margin`` metres, with ``texel`` enlarged where the
    extent would exceed ``max_texels`` a side."""
    lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
    ext = hi - lo
    texel = max(texel, float(ext.max()) / max_texels)
    rows, cols = (int(math.ceil(e / texel)) for e in ext)
    return OrthoGrid(float(hi[0]), float(hi[1]), texel, max(rows, 1), max(cols, 1))


def rectify(image: np.ndarray, rig: PhotoRig, grid: OrthoGrid, interpolation: int | None = None,
            border_value=0) -> np.ndarray:
    """Sample ``image`` (H, W[, C]) at the grid's texel centres through the rig (bilinear by
    default; texels whose point falls outside the image get ``border_value``)."""
    import cv2

    h, w = image.shape[:2]
    x, y = grid.centres()
    uv, z = rig.project(np.column_stack([x.ravel(), y.ravel()]), w, h)
    uv[z <= 0] = -1e6
    mx = uv[:, 0].reshape(grid.rows, grid.cols).astype(np.float32)
    my = uv[:, 1].reshape(grid.rows, grid.cols).astype(np.float32)
    interp = cv2.INTER_LINEAR if interpolation is None else interpolation
    return cv2.remap(image, mx, my, interp, borderMode=cv2.BORDER_CONSTANT, borderValue=border_value)


def pixel_ground_area(u: np.ndarray, v: np.ndarray, rig: PhotoRig, width: int, height: int) -> np.ndarray:
    """Road area (m^2) each pixel covers: |det| of the pixel -> ground Jacobian at its centre."""
    e = 0.5
    p0, _ = rig.backproject(u, v, width, height)
    pu, _ = rig.backproject(u + e, v, width, height)
    pv, _ = rig.backproject(u, v + e, width, height)
    a, b = (pu - p0) / e, (pv - p0) / e
    return np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
