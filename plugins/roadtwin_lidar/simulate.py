"""Ground truth for the LiDAR reconstructor's tests and ``bench/lidar.py``, and how a
reconstruction is scored against it.

:func:`pothole_road_mesh` is an ISO 8608 random road with a smooth bowl pothole subtracted, as a
regular triangle grid; :func:`save_frames` writes NPZ / PLY / PCD frames plus a KITTI or TUM pose
file; :func:`evaluate_surface` measures a reconstruction's height errors and pothole depth against
the ground-truth mesh by vertical rays (open3d's ``RaycastingScene``). The frames themselves come
from the Livox-like rosette scan simulator, which is a sensor model:
``roadtwin_sensors.simulate_scans`` (the ``sensors`` plugin; moved there in issue 20).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from roadtwin_core import iso8608_surface

ROAD_LABEL = 40  # SemanticKITTI "road"


def _raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    """An open3d ``RaycastingScene`` of a triangle mesh (for :class:`LidarSurface` heights and
    :func:`evaluate_surface`; the scan simulator has its own copy in ``roadtwin_sensors``, as a
    plugin imports no other plugin)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    return scene


def _vertical_heights(scene, xy: np.ndarray, top: float = 100.0) -> np.ndarray:
    """Mesh height under each XY (NaN outside the mesh), by downward rays."""
    import open3d as o3d

    rays = np.zeros((len(xy), 6), np.float32)
    rays[:, :2], rays[:, 2], rays[:, 5] = xy, top, -1.0
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
    z = top - t
    z[~np.isfinite(t)] = np.nan
    return z


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
    gt = _raycasting_scene(gt_vertices, gt_faces)
    rec = _raycasting_scene(world_vertices, faces)
    ev = world_vertices[:, 2] - _vertical_heights(gt, world_vertices[:, :2])
    ev = ev[np.isfinite(ev)]
    lo, hi = world_vertices[:, :2].min(0), world_vertices[:, :2].max(0)
    X, Y = np.meshgrid(np.arange(lo[0], hi[0], grid_m), np.arange(lo[1], hi[1], grid_m))
    g = np.column_stack([X.ravel(), Y.ravel()])
    zr = _vertical_heights(rec, g)
    m = np.isfinite(zr)
    eg = zr[m] - _vertical_heights(gt, g[m])
    eg = eg[np.isfinite(eg)]
    out = {"vertices": int(len(world_vertices)), "vertex_rmse_m": float(np.sqrt(np.mean(ev**2))),
           "vertex_max_m": float(np.abs(ev).max()), "grid_points": int(len(eg)),
           "grid_rmse_m": float(np.sqrt(np.mean(eg**2))), "grid_p99_m": float(np.percentile(np.abs(eg), 99)),
           "grid_max_m": float(np.abs(eg).max()), "covered_m2": float(len(eg) * grid_m**2)}
    if pothole_center is not None:
        out["pothole_depth_gt_m"] = pothole_depth(lambda q: _vertical_heights(gt, q), pothole_center, pothole_radius_m)
        out["pothole_depth_rec_m"] = pothole_depth(lambda q: _vertical_heights(rec, q), pothole_center, pothole_radius_m)
    return out
