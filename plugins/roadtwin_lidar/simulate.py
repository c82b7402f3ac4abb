"""LiDAR scan simulator for ground truth: a Livox-like rosette scanner over a known triangle mesh.

Livox Avia / Mid-40-class sensors steer one beam through two counter-rotating Risley prisms; the
beam's deflection is the sum of two rotating vectors whose angular rates are incommensurate, so
the pattern is a rosette that never repeats and fills the field of view more densely the longer
it integrates. :func:`rosette_directions` models exactly that (two equal deflections of
``fov/4`` each, so the beam sweeps through the centre and out to ``fov/2``). Consecutive frames
continue the pattern in time, so every frame lands on new places.

Sensor frame: +Z is the optical axis (the rosette's centre), X right, Y down (camera-like).
Poses are 4x4 sensor-to-world transforms. Ray casting uses open3d's
``RaycastingScene`` (embree); the returned points are in the sensor frame, with Gaussian range
noise added along each ray and random dropouts (plus the rays that hit nothing) removed.

Also here: :func:`pothole_road_mesh`, the ground truth the tests and ``bench/lidar.py`` use (an
ISO 8608 random road with a smooth bowl pothole subtracted, as a regular triangle grid), and
:func:`save_frames` (NPZ / PLY / PCD frames plus a KITTI or TUM pose file).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from roadtwin_core import iso8608_surface

ROAD_LABEL = 40  # SemanticKITTI "road"


@dataclass
class RosetteScanner:
    fov_deg: float = 70.4          # circular field of view (Livox Avia: 70.4 deg)
    points_per_frame: int = 24000  # 240 kHz x 0.1 s
    frame_s: float = 0.1
    f1_hz: float = 1180.0          # prism rates: opposite directions, incommensurate ratio
    f2_hz: float = 1180.0 * (math.sqrt(5.0) - 1.0) / 2.0 * 1.3
    range_sigma_m: float = 0.02
    dropout: float = 0.05          # fraction of returns lost at random
    max_range_m: float = 60.0


def rosette_directions(n: int, t0: float, duration: float, fov_deg: float, f1_hz: float,
                       f2_hz: float) -> np.ndarray:
    """(n, 3) unit beam directions in the sensor frame over ``[t0, t0 + duration)``."""
    t = t0 + np.arange(n, dtype=np.float64) * (duration / n)
    a = math.radians(fov_deg) / 4.0
    w1, w2 = 2.0 * math.pi * f1_hz, -2.0 * math.pi * f2_hz
    ax = a * (np.cos(w1 * t) + np.cos(w2 * t))
    ay = a * (np.sin(w1 * t) + np.sin(w2 * t))
    ang = np.hypot(ax, ay)
    az = np.arctan2(ay, ax)
    s = np.sin(ang)
    return np.column_stack([s * np.cos(az), s * np.sin(az), np.cos(ang)])


def _rot(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    X = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Z @ Y @ X


def path_poses(n_frames: int, start=(0.0, 0.0), step_m: float = 0.3, height_m: float = 1.8,
               jitter_deg: float = 1.5, seed: int = 0) -> np.ndarray:
    """Sensor-to-world poses along +X, looking down (optical axis -Z), with small attitude jitter."""
    rng = np.random.default_rng(seed)
    down = np.diag([1.0, -1.0, -1.0])  # sensor X->world X, Y->-Y, Z->-Z
    poses = np.zeros((n_frames, 4, 4))
    for i in range(n_frames):
        j = np.radians(rng.uniform(-jitter_deg, jitter_deg, 3))
        poses[i, :3, :3] = _rot(*j) @ down
        poses[i, :3, 3] = [start[0] + i * step_m, start[1] + rng.uniform(-0.05, 0.05),
                           height_m + rng.uniform(-0.03, 0.03)]
        poses[i, 3, 3] = 1.0
    return poses


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    return scene


def cast(scene, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Hit distances along unit ``dirs`` (inf where nothing is hit)."""
    import open3d as o3d

    rays = np.ascontiguousarray(np.hstack([origins, dirs]), np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def vertical_heights(scene, xy: np.ndarray, top: float = 100.0) -> np.ndarray:
    """Mesh height under each XY (NaN outside the mesh), by downward rays."""
    o = np.column_stack([xy, np.full(len(xy), top)])
    d = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    t = cast(scene, o, d)
    z = top - t
    z[~np.isfinite(t)] = np.nan
    return z


def simulate_scans(vertices: np.ndarray, faces: np.ndarray, poses: np.ndarray,
                   scanner: RosetteScanner | None = None, seed: int = 0):
    """Scan the mesh from each pose. Returns ``(frames, poses)``: a list of (N_i, 3) point arrays
    in the sensor frame and the (F, 4, 4) sensor-to-world poses."""
    sc = scanner or RosetteScanner()
    rng = np.random.default_rng(seed)
    scene = raycasting_scene(vertices, faces)
    frames = []
    for i, pose in enumerate(np.asarray(poses, np.float64)):
        d_s = rosette_directions(sc.points_per_frame, i * sc.frame_s, sc.frame_s, sc.fov_deg, sc.f1_hz, sc.f2_hz)
        d_w = d_s @ pose[:3, :3].T
        t = cast(scene, np.tile(pose[:3, 3], (len(d_w), 1)), d_w)
        keep = np.isfinite(t) & (t <= sc.max_range_m) & (rng.random(len(t)) >= sc.dropout)
        r = t[keep] + rng.normal(0.0, sc.range_sigma_m, int(keep.sum()))
        frames.append(d_s[keep] * r[:, None])
    return frames, np.asarray(poses, np.float64)


def bowl_depth(xy: np.ndarray, center=(0.0, 0.0), radius_m: float = 0.35, depth_m: float = 0.05) -> np.ndarray:
    """Smooth (raised-cosine) bowl: ``depth`` at the centre, 0 with zero slope at ``radius``."""
    rho = np.hypot(xy[:, 0] - center[0], xy[:, 1] - center[1])
    return np.where(rho < radius_m, depth_m * 0.5 * (1.0 + np.cos(np.pi * np.minimum(rho / radius_m, 1.0))), 0.0)


def pothole_road_mesh(bounds=(-2.0, -2.0, 5.0, 2.0), road_class: str = "C", seed: int = 0,
                      pothole_center=(1.35, 0.2), pothole_radius_m: float = 0.35,
                      pothole_depth_m: float = 0.05, dx: float = 0.02):
    """Ground truth: ISO 8608 road (``roadtwin_core.iso8608_surface``) minus a bowl pothole,
    as a regular triangle grid of spacing ``dx``. Returns ``(vertices, faces, height_fn)``."""
    rough = iso8608_surface(road_class, bounds, seed, dx=0.05)
    xmin, ymin, xmax, ymax = bounds
    xs = np.arange(xmin, xmax + dx / 2, dx)
    ys = np.arange(ymin, ymax + dx / 2, dx)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])

    def height(q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(q)
        return rough.height(q) - bowl_depth(q, pothole_center, pothole_radius_m, pothole_depth_m)

    verts = np.column_stack([xy, height(xy)])
    ny, nx = X.shape
    i, j = np.meshgrid(np.arange(ny - 1), np.arange(nx - 1), indexing="ij")
    a = (i * nx + j).ravel()
    b, c, d = a + 1, a + nx, a + nx + 1
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return verts, faces, height


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """(qx, qy, qz, qw) of a rotation matrix."""
    return Rotation.from_matrix(R).as_quat()


def save_frames(folder: str | Path, frames: list[np.ndarray], poses: np.ndarray, fmt: str = "npz",
                pose_format: str = "kitti", labels: list[np.ndarray] | None = None) -> tuple[list[Path], Path]:
    """Write ``frame_000.<fmt>`` files and ``poses.txt`` (KITTI 3x4 rows or TUM lines)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, pts in enumerate(frames):
        p = folder / f"frame_{i:03d}.{fmt}"
        if fmt == "npz":
            extra = {} if labels is None else {"labels": labels[i]}
            np.savez(p, points=pts, **extra)
        else:
            import open3d as o3d

            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(pts, np.float64)))
            if not o3d.io.write_point_cloud(str(p), pc):
                raise OSError(f"{p}: cannot write")
        paths.append(p)
    lines = []
    for i, T in enumerate(poses):
        if pose_format == "kitti":
            lines.append(" ".join(f"{v:.9g}" for v in T[:3, :4].ravel()))
        else:
            q = rot_to_quat(T[:3, :3])
            lines.append(" ".join(f"{v:.9g}" for v in [i * 0.1, *T[:3, 3], *q]))
    pose_path = folder / "poses.txt"
    pose_path.write_text(("# timestamp tx ty tz qx qy qz qw\n" if pose_format == "tum" else "") + "\n".join(lines) + "\n")
    return paths, pose_path


def pothole_depth(height_fn, center, radius_m: float) -> float:
    """Depth of a pothole on a surface: median height of the ring [1.3 R, 1.8 R] minus the height
    at the centre (the same measure for ground truth and reconstruction)."""
    ang = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    rr = np.linspace(1.3 * radius_m, 1.8 * radius_m, 6)
    ring = np.array([[center[0] + r * np.cos(a), center[1] + r * np.sin(a)] for r in rr for a in ang])
    return float(np.nanmedian(height_fn(ring)) - height_fn(np.array([center], np.float64))[0])


def evaluate_surface(world_vertices: np.ndarray, faces: np.ndarray, gt_vertices: np.ndarray, gt_faces: np.ndarray,
                     grid_m: float = 0.02, pothole_center=None, pothole_radius_m: float = 0.35) -> dict:
    """Height errors of a reconstruction (vertices in the ground-truth world frame) vs the
    ground-truth mesh: at the reconstructed vertices and on a ``grid_m`` grid over the area the
    reconstruction covers (both by vertical rays); plus the pothole depth of both."""
    gt = raycasting_scene(gt_vertices, gt_faces)
    rec = raycasting_scene(world_vertices, faces)
    ev = world_vertices[:, 2] - vertical_heights(gt, world_vertices[:, :2])
    ev = ev[np.isfinite(ev)]
    lo, hi = world_vertices[:, :2].min(0), world_vertices[:, :2].max(0)
    X, Y = np.meshgrid(np.arange(lo[0], hi[0], grid_m), np.arange(lo[1], hi[1], grid_m))
    g = np.column_stack([X.ravel(), Y.ravel()])
    zr = vertical_heights(rec, g)
    m = np.isfinite(zr)
    eg = zr[m] - vertical_heights(gt, g[m])
    eg = eg[np.isfinite(eg)]
    out = {"vertices": int(len(world_vertices)), "vertex_rmse_m": float(np.sqrt(np.mean(ev**2))),
           "vertex_max_m": float(np.abs(ev).max()), "grid_points": int(len(eg)),
           "grid_rmse_m": float(np.sqrt(np.mean(eg**2))), "grid_p99_m": float(np.percentile(np.abs(eg), 99)),
           "grid_max_m": float(np.abs(eg).max()), "covered_m2": float(len(eg) * grid_m**2)}
    if pothole_center is not None:
        out["pothole_depth_gt_m"] = pothole_depth(lambda q: vertical_heights(gt, q), pothole_center, pothole_radius_m)
        out["pothole_depth_rec_m"] = pothole_depth(lambda q: vertical_heights(rec, q), pothole_center, pothole_radius_m)
    return out
