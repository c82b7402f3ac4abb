"""Scan patterns of Livox LiDARs, and the stand-alone scan simulator over a triangle mesh.

:class:`RosetteScanner`, :func:`rosette_directions`, :func:`path_poses`, :func:`raycasting_scene`,
:func:`cast`, :func:`vertical_heights` and :func:`simulate_scans` are the Livox Avia /
Mid-40-class rosette simulator that the LiDAR reconstructor's tests and ``bench/lidar.py`` scan a
known mesh with (it lived in ``roadtwin_lidar/simulate.py`` until issue 20);
:func:`mid360_directions` is the Mid-360's 360 x 59 degree non-repetitive coverage, which the
``lidar`` sensor of a drive uses.

Livox Avia / Mid-40-class sensors steer one beam through two counter-rotating Risley prisms; the
beam's deflection is the sum of two rotating vectors whose angular rates are incommensurate, so
the pattern is a rosette that never repeats and fills the field of view more densely the longer
it integrates. :func:`rosette_directions` models exactly that (two equal deflections of
``fov/4`` each, so the beam sweeps through the centre and out to ``fov/2``). Consecutive frames
continue the pattern in time, so every frame lands on new places.

Rosette sensor frame: +Z is the optical axis (the rosette's centre), X right, Y down
(camera-like). Poses are 4x4 sensor-to-world transforms. Ray casting uses open3d's
``RaycastingScene`` (embree); the returned points are in the sensor frame, with Gaussian range
noise added along each ray and random dropouts (plus the rays that hit nothing) removed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._mount import returns


def mid360_directions(n: int, t0: float, duration: float, vfov_deg=(-7.0, 52.0), f_az_hz: float = 10.0,
                      f1_hz: float = 1373.7, f2_hz: float = 1373.7 * (math.sqrt(5.0) - 1.0) / 2.0) -> np.ndarray:
    """(n, 3) unit beam directions, Livox frame (x forward, y left, z up), over ``[t0, t0 + duration)``:
    Mid-360-like coverage (360 degrees around z, ``vfov_deg`` in elevation; the Mid-360 data sheet:
    -7 to 52 degrees, 200,000 points/s). The azimuth turns at ``f_az_hz`` while the elevation swings
    with two incommensurate rates, so, like the real sensor's (undisclosed) pattern, it never
    repeats and fills the field of view the longer it integrates. A model of the coverage, not
    Livox's exact pattern."""
    t = t0 + np.arange(n, dtype=np.float64) * (duration / n)
    az = 2.0 * math.pi * f_az_hz * t
    u = 0.5 + 0.25 * (np.sin(2.0 * math.pi * f1_hz * t) + np.sin(2.0 * math.pi * f2_hz * t + 1.0))
    el = np.radians(vfov_deg[0] + (vfov_deg[1] - vfov_deg[0]) * u)
    ce = np.cos(el)
    return np.column_stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)])


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
        keep, r = returns(t, rng, 0.0, sc.max_range_m, sc.dropout, sc.range_sigma_m)
        frames.append(d_s[keep] * r[:, None])
    return frames, np.asarray(poses, np.float64)


