"""Ground truth for tests and benchmarks: exact disparity maps of a road plane with a bowl
pothole, by ray-surface intersection (core-free).

Camera: pinhole K (fx = fy = f), rectified stereo baseline B, X right, Y down, Z forward. The road
plane has unit "up" normal ``n`` (pointing to the camera side) and the camera sits ``H`` above
it: ``n . P = -H``. The bowl is a paraboloid ``z = -D (1 - r^2 / R^2)`` (r < R) in an in-plane frame
centred at ``center`` (a point on the plane). Disparity = f B / Z of the first surface point hit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates
from scipy.spatial import cKDTree


@dataclass
class BowlScene:
    f: float = 700.0
    width: int = 640
    height: int = 480
    baseline: float = 0.12
    tilt_deg: float = 30.0     # angle between the optical axis and -n (0: looking straight down)
    roll_deg: float = 0.0      # camera roll about the optical axis
    distance: float = 1.5      # range along the optical axis to the road plane
    depth: float = 0.05        # bowl depth D (m)
    radius: float = 0.25       # bowl radius R (m)
    offset: tuple[float, float] = (0.0, 0.0)  # bowl centre offset in the plane from the axis point (m)
    K: np.ndarray = field(init=False)
    n: np.ndarray = field(init=False)
    H: float = field(init=False)
    center: np.ndarray = field(init=False)
    e1: np.ndarray = field(init=False)
    e2: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        a, r = np.radians(self.tilt_deg), np.radians(self.roll_deg)
        n0 = np.array([0.0, -np.sin(a), -np.cos(a)])
        rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
        self.n = rz @ n0
        self.H = -self.n[2] * self.distance
        self.K = np.array([[self.f, 0, self.width / 2 - 0.5], [0, self.f, self.height / 2 - 0.5], [0, 0, 1.0]])
        e1 = np.array([1.0, 0, 0]) - self.n * self.n[0]
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.n, self.e1)
        self.center = np.array([0, 0, self.distance]) + self.offset[0] * self.e1 + self.offset[1] * self.e2

    @property
    def roll_angle_image(self) -> float:
        """The image-space roll of the iso-disparity lines (Fan et al.'s theta) for this camera:
        road disparity is affine in -(n_x u + n_y v), i.e. constant along v' = u sin t + v cos t
        with t = atan2(-n_x, -n_y) (= minus the camera roll)."""
        return float(np.arctan2(-self.n[0], -self.n[1]))

    def bowl(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        r2 = (x * x + y * y) / self.radius ** 2
        return np.where(r2 < 1, -self.depth * (1 - r2), 0.0)

    def to_local(self, p: np.ndarray) -> np.ndarray:
        """Camera points (N,3) -> bowl frame (x, y in the plane, z above the plane)."""
        q = p - self.center
        return np.stack([q @ self.e1, q @ self.e2, p @ self.n + self.H], axis=-1)

    def depth_map(self, cam_x: float = 0.0) -> np.ndarray:
        """Camera Z of the first hit, by bisection on the ray parameter (vectorised); ``cam_x``
        shifts the camera along X (the right camera of the pair sits at ``cam_x = baseline``)."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        ray = np.stack([(u - self.K[0, 2]) / self.f, (v - self.K[1, 2]) / self.f, np.ones_like(u)], -1)
        o = np.array([cam_x, 0.0, 0.0])
        nr = ray @ self.n  # < 0 where the ray meets the plane
        if (nr >= 0).any():
            raise ValueError("some pixels see no road (above the horizon)")
        h0 = o @ self.n + self.H                          # camera height above the plane
        t_lo = h0 / -nr                                   # on the plane: height 0 >= bowl
        t_hi = (h0 + 1.01 * self.depth) / -nr             # below the bowl bottom
        for _ in range(32):
            t = 0.5 * (t_lo + t_hi)
            p = o + ray * t[..., None]
            loc = self.to_local(p.reshape(-1, 3)).reshape(p.shape)
            g = loc[..., 2] - self.bowl(loc[..., 0], loc[..., 1])
            above = g > 0
            t_lo = np.where(above, t, t_lo)
            t_hi = np.where(above, t_hi, t)
        return 0.5 * (t_lo + t_hi)  # ray z component is 1, so t = Z

    def stereo_pair(self, seed: int = 0, texture_m: float = 0.004, noise: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
        """A rendered rectified pair (uint8 gray) of the road with a random texture fixed on the
        surface (cells of ``texture_m``), the right camera ``baseline`` to the right."""
        rng = np.random.default_rng(seed)
        ext = 2.0 * self.distance  # covers the view of any camera here (half-angle < 35 deg, tilt <= 45)
        n = int(2 * ext / texture_m)
        tex = gaussian_filter(rng.random((n, n)), 0.7)
        tex = (tex - tex.min()) / np.ptp(tex)
        out = []
        for cam_x in (0.0, self.baseline):
            z = self.depth_map(cam_x)
            v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
            p = np.stack([cam_x + (u - self.K[0, 2]) / self.f * z, (v - self.K[1, 2]) / self.f * z, z], -1)
            loc = self.to_local(p.reshape(-1, 3))
            g = map_coordinates(tex, [(loc[:, 1] + ext) / texture_m, (loc[:, 0] + ext) / texture_m], order=1, mode="reflect")
            img = 30 + 200 * g.reshape(z.shape) + rng.normal(0, noise, z.shape)
            out.append(np.clip(img, 0, 255).astype(np.uint8))
        return out[0], out[1]

    def disparity(self, noise_px: float = 0.0, seed: int = 0) -> np.ndarray:
        d = self.f * self.baseline / self.depth_map()
        if noise_px > 0:
            d = d + np.random.default_rng(seed).normal(0, noise_px, d.shape)
        return d

    def surface_samples(self, step: float = 0.002, margin: float = 1.1) -> np.ndarray:
        """Dense samples of the true surface (bowl and the plane around it) in the bowl frame."""
        g = np.arange(-margin * self.radius, margin * self.radius + step / 2, step)
        x, y = np.meshgrid(g, g)
        return np.stack([x.ravel(), y.ravel(), self.bowl(x, y).ravel()], -1)

    @property
    def volume(self) -> float:
        return float(np.pi * self.depth * self.radius ** 2 / 2)


def mesh_samples(vertices: np.ndarray, faces: np.ndarray, per_face: int = 6) -> np.ndarray:
    """Vertices plus ``per_face`` fixed barycentric samples of every triangle."""
    bary = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3],
                     [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5]])[:per_face]
    tri = vertices[faces]
    return np.concatenate([vertices, np.einsum("kj,fjc->fkc", bary, tri).reshape(-1, 3)])


def hausdorff_to_bowl(scene: BowlScene, recon_camera_points: np.ndarray, step: float = 0.001) -> tuple[float, float]:
    """(symmetric Hausdorff, mean distance) in m between reconstructed surface samples (camera
    coordinates) and the true surface: reconstruction -> true surface (bowl and plane around it),
    and true bowl (r <= R) -> reconstruction."""
    rec = scene.to_local(recon_camera_points)
    true = scene.surface_samples(step=step, margin=2.0)
    d1, _ = cKDTree(true).query(rec)
    bowl = true[(true[:, 0] ** 2 + true[:, 1] ** 2) <= scene.radius ** 2]
    d2, _ = cKDTree(rec).query(bowl)
    return float(max(d1.max(), d2.max())), float(np.concatenate([d1, d2]).mean())


@dataclass
class RoadScene(BowlScene):
    """An undulating road with several bowl potholes, for the local road model's tests: the height
    above the reference plane at in-plane (x across, y along) is a cross-slope ``cross_slope x``,
    a crown ``-crown |x - crown_x|``, undulations ``sum a sin(2 pi y / L + phase)`` (``waves``:
    (a, L, phase) rows, ISO 8608 class C-D amplitudes) and the paraboloid bowls
    ``-D (1 - r^2 / R^2)`` of ``potholes`` ((x, y, R, D) rows, x, y relative to ``center``)."""

    cross_slope: float = 0.02
    crown: float = 0.0
    crown_x: float = 0.0
    waves: tuple = ((0.02, 8.0, 0.3), (0.008, 3.0, 1.1), (0.003, 1.2, 2.0))
    potholes: tuple = ((0.0, 0.0, 0.25, 0.05),)

    def road(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        z = self.cross_slope * x - self.crown * np.abs(x - self.crown_x)
        for a, wl, ph in self.waves:
            z = z + a * np.sin(2 * np.pi * y / wl + ph)
        return z

    def bowl(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        z = self.road(x, y)
        for px, py, r, d in self.potholes:
            r2 = ((x - px) ** 2 + (y - py) ** 2) / r ** 2
            z = z + np.where(r2 < 1, -d * (1 - r2), 0.0)
        return z

    def depth_map(self, cam_x: float = 0.0) -> np.ndarray:
        """Camera Z of the first hit (bisection between planes above and below every surface point)."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        ray = np.stack([(u - self.K[0, 2]) / self.f, (v - self.K[1, 2]) / self.f, np.ones_like(u)], -1)
        o = np.array([cam_x, 0.0, 0.0])
        nr = ray @ self.n
        if (nr >= 0).any():
            raise ValueError("some pixels see no road (above the horizon)")
        reach = sum(abs(a) for a, _, _ in self.waves) + abs(self.cross_slope) * 20 + self.crown * 20
        deepest = max((d for *_, d in self.potholes), default=0.0)
        h0 = o @ self.n + self.H
        t_lo = np.maximum(h0 - reach, 1e-3) / -nr
        t_hi = (h0 + reach + 1.01 * deepest) / -nr
        for _ in range(40):
            t = 0.5 * (t_lo + t_hi)
            p = o + ray * t[..., None]
            loc = self.to_local(p.reshape(-1, 3)).reshape(p.shape)
            above = loc[..., 2] - self.bowl(loc[..., 0], loc[..., 1]) > 0
            t_lo = np.where(above, t, t_lo)
            t_hi = np.where(above, t_hi, t)
        return 0.5 * (t_lo + t_hi)

    def pothole_masks(self) -> list[np.ndarray]:
        """Closed-form truth: per pothole, the pixels whose first hit lies inside its rim."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        z = self.depth_map()
        p = np.stack([(u - self.K[0, 2]) / self.f * z, (v - self.K[1, 2]) / self.f * z, z], -1)
        loc = self.to_local(p.reshape(-1, 3)).reshape(p.shape)
        return [(loc[..., 0] - px) ** 2 + (loc[..., 1] - py) ** 2 < r ** 2 for px, py, r, _ in self.potholes]
