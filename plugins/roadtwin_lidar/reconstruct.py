"""Coarse stream kernels: LiDAR frames + poses -> a Z-up road surface triangle mesh.

Steps (the paper's hierarchical road model creator, coarse stream):

1. read frames (PLY / PCD through open3d, NPZ with ``points`` and optional ``labels``) and poses
   (KITTI: 12 numbers per line, a 3x4 sensor-to-world matrix; TUM: ``t x y z qx qy qz qw``);
   one frame with no poses is taken as already in world coordinates;
2. keep road points -- per-point labels in ``road_labels``, and/or per-frame semantic masks
   (:func:`mask_road_points`: the points are projected into a camera with intrinsics K and a
   camera-from-LiDAR extrinsic, and kept where they land on a non-zero mask pixel; the masks
   stand in for Grounded-SAM's road/pavement output); no labels and no masks = every point is
   road -- and fuse the frames into world coordinates;
3. fit the ground plane with RANSAC (open3d ``segment_plane``, seeded), refine it by least squares
   on the inliers and rotate it to Z-up with the plane at z = 0 (the 4x4 ``alignment`` is kept, so
   the result can be mapped back to the input world frame);
4. even out the density by an open3d voxel downsample of the XY projection (vertex = the centroid
   of a column of points, so noisy heights never split a column into two vertices);
5. Delaunay-triangulate the XY vertices (scipy) and drop triangles with an edge longer than
   ``k x`` the median edge, so the outline follows the data;
6. restore each vertex's elevation from the *original* points: a local plane fit of the up to
   ``max_neighbors`` nearest points within ``radius_m`` (XY), refitted once without residuals
   beyond ``3 x 1.4826 x MAD``; the plane's value at the vertex is its height. Vertices with too
   few neighbours are removed with their triangles.

Mask projection: points behind the camera (depth <= 0) and points that land outside the image
are dropped (they cannot be shown to be road). A frame left with no road point is an error naming
the frame and its mask (as with labels), not skipped: a mask that misses the road is almost always
a mismatched mask, calibration or frame order.
"""
from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay, cKDTree
from scipy.spatial.transform import Rotation

from roadtwin_core import RoadtwinError
from roadtwin_core.render import camera_matrix


# ---------------------------------------------------------------------------- input
MAX_COORD_M = 1e7  # a point farther than 10,000 km from the origin is a corrupt file


def load_frame(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3) float64 points and optional (N,) integer labels of one frame file."""
    p = Path(path)
    if p.is_dir():
        raise RoadtwinError(f"{p}: is a directory, not a point cloud file")
    if not p.exists():
        raise RoadtwinError(f"{p}: no such point cloud file")
    suffix = p.suffix.lower()
    if suffix not in (".npz", ".npy", ".ply", ".pcd", ".xyz", ".pts"):
        raise RoadtwinError(f"{p}: unsupported point cloud format {suffix!r} (use .ply, .pcd, .npz, .npy)")
    try:
        pts, labels = _read_frame(p, suffix)
    except RoadtwinError:
        raise
    except Exception as exc:  # numpy / zipfile / open3d raise many kinds on a corrupt file
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RoadtwinError(f"{p}: cannot read the point cloud ({first})") from None
    return check_points(pts, labels, str(p))


def check_points(pts: np.ndarray, labels: np.ndarray | None, name: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Shape, labels and finiteness of one frame; non-finite points are dropped."""
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise RoadtwinError(f"{name}: expected an (N, 3) point array, got shape {pts.shape}")
    pts = pts[:, :3]
    if labels is not None and len(labels) != len(pts):
        raise RoadtwinError(f"{name}: {len(labels)} labels for {len(pts)} points")
    if len(pts) == 0:
        raise RoadtwinError(f"{name}: empty point cloud")
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        raise RoadtwinError(f"{name}: no finite points (all NaN/inf)")
    far = np.abs(pts[finite]).max()
    if far > MAX_COORD_M:
        raise RoadtwinError(f"{name}: a coordinate of {far:.3g} m is absurd (at most {MAX_COORD_M:g} m from the origin)")
    return pts[finite], (None if labels is None else labels[finite])


def _read_frame(p: Path, suffix: str) -> tuple[np.ndarray, np.ndarray | None]:
    labels = None
    if suffix == ".npz":
        with np.load(p, allow_pickle=False) as z:
            if "points" not in z.files:
                raise RoadtwinError(f"{p}: no array 'points' in the NPZ (found: {', '.join(z.files) or 'none'})")
            pts = _real(z["points"], p)
            for lk in ("labels", "label", "semantic"):
                if lk in z.files:
                    labels = np.asarray(z[lk]).ravel().astype(np.int64)
                    break
    elif suffix == ".npy":
        pts = _real(np.load(p, allow_pickle=False), p)
    else:
        import open3d as o3d

        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            pc = o3d.t.io.read_point_cloud(str(p))
        if "positions" not in pc.point:
            raise RoadtwinError(f"{p}: empty or unreadable point cloud (no points read)")
        pts = pc.point["positions"].numpy().astype(np.float64)
        _check_complete(p, suffix, len(pts))
        for lk in ("label", "labels", "semantic"):
            if lk in pc.point:
                labels = pc.point[lk].numpy().ravel().astype(np.int64)
                break
    return pts, labels


def _real(a: np.ndarray, p: Path) -> np.ndarray:
    if a.dtype.kind not in "iuf":
        raise RoadtwinError(f"{p}: points must be real numbers, got dtype {a.dtype}")
    return np.asarray(a, dtype=np.float64)


def _check_complete(p: Path, suffix: str, n_read: int) -> None:
    """open3d pads a truncated file's missing points with zeros: compare the point count the
    header declares (PLY ``element vertex N``, PCD ``POINTS N``) with what the body holds
    (ASCII: data lines; binary: at least 12 bytes, three float32, a point)."""
    raw = p.read_bytes()
    head = raw[:65536].decode("latin-1")
    m = re.search(r"^element vertex (\d+)" if suffix == ".ply" else r"^POINTS (\d+)", head, re.M)
    end = re.search(r"^end_header\s*$" if suffix == ".ply" else r"^DATA \w+\s*$", head, re.M)
    if m is None or end is None:
        return
    declared = int(m.group(1))
    ascii_body = re.search(r"^format ascii" if suffix == ".ply" else r"^DATA ascii", head, re.M) is not None
    body = raw[end.end():]
    held = (len([ln for ln in body.split(b"\n") if ln.strip()]) if ascii_body else len(body) // 12)
    if held < declared or n_read != declared:
        raise RoadtwinError(f"{p}: truncated: the header declares {declared} points, the file holds "
                            f"{min(held, n_read)}")


def load_poses(path: str | Path) -> np.ndarray:
    """(F, 4, 4) sensor-to-world poses from a KITTI (12 numbers/line) or TUM (8 numbers/line) file."""
    p = Path(path)
    if p.is_dir():
        raise RoadtwinError(f"{p}: is a directory, not a pose file")
    if not p.exists():
        raise RoadtwinError(f"{p}: no such pose file")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RoadtwinError(f"{p}: cannot read the pose file ({exc})") from None
    poses = []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.split("#", 1)[0].replace(",", " ").split()
        if not s:
            continue
        try:
            v = np.array([float(x) for x in s])
        except ValueError:
            raise RoadtwinError(f"{p}:{n}: not a number in pose line {line.strip()!r}") from None
        if not np.isfinite(v).all():
            raise RoadtwinError(f"{p}:{n}: pose has NaN/inf")
        T = np.eye(4)
        if len(v) == 12:
            T[:3, :4] = v.reshape(3, 4)
        elif len(v) == 8:
            q = v[4:8]
            if np.linalg.norm(q) < 1e-9:
                raise RoadtwinError(f"{p}:{n}: zero quaternion")
            T[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
            T[:3, 3] = v[1:4]
        else:
            raise RoadtwinError(f"{p}:{n}: expected 12 numbers (KITTI) or 8 (TUM: t x y z qx qy qz qw), got {len(v)}")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
            raise RoadtwinError(f"{p}:{n}: the pose's rotation is not a rotation (orthonormal, det +1)")
        if np.abs(T[:3, 3]).max() > MAX_COORD_M:
            raise RoadtwinError(f"{p}:{n}: the pose's position is absurdly far (beyond {MAX_COORD_M:g} m)")
        poses.append(T)
    if not poses:
        raise RoadtwinError(f"{p}: no poses")
    return np.asarray(poses)


def fuse_frames(frames: list[tuple[np.ndarray, np.ndarray | None]], poses: np.ndarray | None,
                names: list[str], road_labels: tuple[int, ...] | None, poses_name: str = "poses") -> np.ndarray:
    """Road points of every frame in world coordinates."""
    if not frames:
        raise RoadtwinError("no point cloud frames given")
    if poses is None:
        if len(frames) != 1:
            raise RoadtwinError(f"{len(frames)} frames need a pose file (only one frame may be given without poses)")
        poses = np.eye(4)[None]
    elif len(poses) != len(frames):
        raise RoadtwinError(f"{poses_name}: {len(poses)} poses for {len(frames)} frames")
    out = []
    for (pts, labels), T, name in zip(frames, poses, names):
        if labels is not None and road_labels is not None:
            pts = pts[np.isin(labels, np.asarray(road_labels))]
            if len(pts) == 0:
                raise RoadtwinError(f"{name}: no road points (labels {sorted(road_labels)})")
        out.append(pts @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(out)


# ---------------------------------------------------------------------------- semantic masks
def load_extrinsic(src, what: str = "cam_from_lidar") -> np.ndarray:
    """4x4 camera-from-LiDAR transform from an array or a text file (16 numbers, or 12 = 3x4)."""
    name = what
    if isinstance(src, (str, Path)):
        p = Path(src)
        name = str(p)
        if not p.exists():
            raise RoadtwinError(f"{p}: no such extrinsic file")
        try:
            vals = [float(x) for line in p.read_text().splitlines()
                    for x in line.split("#", 1)[0].replace(",", " ").split()]
        except ValueError:
            raise RoadtwinError(f"{p}: extrinsic: not a number") from None
        a = np.asarray(vals)
    else:
        a = np.asarray(src, dtype=np.float64).ravel()
    if a.size == 12:
        a = np.r_[a, 0.0, 0.0, 0.0, 1.0]
    if a.size != 16 or not np.isfinite(a).all():
        raise RoadtwinError(f"{name}: the camera-from-LiDAR extrinsic must be a 4x4 (or 3x4) matrix, got {a.size} numbers")
    T = a.reshape(4, 4)
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
        raise RoadtwinError(f"{name}: the camera-from-LiDAR extrinsic must be a rigid transform "
                            "(orthonormal rotation, last row 0 0 0 1)")
    return T


def load_mask(src, what: str = "mask") -> tuple[np.ndarray, str]:
    """(H, W) boolean road mask (non-zero in any channel = road) from a path or an array."""
    if isinstance(src, np.ndarray):
        m, name = src, what
    else:
        import cv2

        p = Path(src)
        name = str(p)
        if not p.exists():
            raise RoadtwinError(f"{p}: no such mask image")
        m = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if m is None:
            raise RoadtwinError(f"{p}: cannot read mask image")
    m = np.asarray(m)
    if m.ndim == 3:
        m = (m != 0).any(axis=2)
    if m.ndim != 2 or m.size == 0:
        raise RoadtwinError(f"{name}: expected a 2D mask image, got shape {m.shape}")
    return m != 0, name


def mask_road_points(points: np.ndarray, mask: np.ndarray, K: np.ndarray, cam_from_lidar: np.ndarray) -> np.ndarray:
    """(N,) bool: sensor-frame ``points`` that project in front of the camera onto a road pixel
    of ``mask`` (pixel centres at integer coordinates; behind the camera or outside: False)."""
    pc = points @ cam_from_lidar[:3, :3].T + cam_from_lidar[:3, 3]
    keep = np.zeros(len(points), dtype=bool)
    front = pc[:, 2] > 1e-6
    if not front.any():
        return keep
    uvw = pc[front] @ K.T
    u = np.floor(uvw[:, 0] / uvw[:, 2] + 0.5)
    v = np.floor(uvw[:, 1] / uvw[:, 2] + 0.5)
    h, w = mask.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    hit = np.zeros(len(u), dtype=bool)
    hit[inside] = mask[v[inside].astype(np.int64), u[inside].astype(np.int64)]
    keep[np.flatnonzero(front)] = hit
    return keep


# ---------------------------------------------------------------------------- ground plane
def ground_alignment(points: np.ndarray, distance_m: float, seed: int = 0) -> np.ndarray:
    """4x4 world -> surface transform: the RANSAC ground plane becomes z = 0, normal +Z."""
    import open3d as o3d

    o3d.utility.random.seed(seed)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    _, inliers = pc.segment_plane(distance_threshold=distance_m, ransac_n=3, num_iterations=500)
    inl = points[np.asarray(inliers, dtype=np.int64)]
    if len(inl) < 3:
        raise RoadtwinError("ground plane: RANSAC found no plane")
    c = inl.mean(axis=0)
    _, _, vt = np.linalg.svd(inl - c, full_matrices=False)
    n = vt[2]
    if n[2] < 0:
        n = -n
    # Rotation taking n to +Z (Rodrigues), about the inlier centroid.
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, z)
    s, cth = np.linalg.norm(v), float(n @ z)
    if s < 1e-12:
        R = np.eye(3)
    else:
        k = v / s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + s * K + (1 - cth) * K @ K
    T = np.eye(4)
    T[:3, :3] = R
    # The inlier centroid keeps its XY and goes to z = 0, so the plane is z = 0 afterwards.
    T[:3, 3] = -R @ c + np.array([c[0], c[1], 0.0])
    return T


def apply(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ T[:3, :3].T + T[:3, 3]


# ---------------------------------------------------------------------------- mesh
def xy_voxel_vertices(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """(V, 2) XY centroids of the occupied ``voxel_m`` columns (open3d voxel downsample)."""
    import open3d as o3d

    flat = np.column_stack([points[:, :2], np.zeros(len(points))])
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(flat))
    return np.asarray(pc.voxel_down_sample(voxel_m).points)[:, :2]


def delaunay_trimmed(xy: np.ndarray, k_edge: float) -> np.ndarray:
    """Delaunay triangles of ``xy`` without those having an edge > ``k_edge`` x median edge."""
    if len(xy) < 3:
        raise RoadtwinError("surface: fewer than 3 vertices to triangulate")
    tri = Delaunay(xy).simplices
    e = np.stack([np.linalg.norm(xy[tri[:, (i + 1) % 3]] - xy[tri[:, i]], axis=1) for i in range(3)], axis=1)
    med = np.median(e)
    return tri[(e <= k_edge * med).all(axis=1)]


def local_heights(points: np.ndarray, xy: np.ndarray, radius_m: float, max_neighbors: int,
                  min_points: int, tree: cKDTree | None = None, slope_prior: float = 0.0,
                  curvature_prior: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Robust local-surface heights of ``points`` at ``xy``; returns (z, n_used) (NaN where too few).

    The model is a plane ``z = c0 + c1 dx + c2 dy`` in the vertex's neighbourhood, or with
    ``curvature_prior`` > 0 a quadric (``+ c3 dx^2 + c4 dx dy + c5 dy^2``); its value ``c0`` at the
    vertex is the height. A plane over a radius r flattens a bowl of curvature k by about
    k r^2 / 4 (3 mm at the bottom of a 5 cm deep, 35 cm pothole with r = 8 cm); the quadric
    removes that bias, and its extra noise is held down by the prior.

    Priors are zero-mean Gaussians of the given standard deviation on the slopes (``slope_prior``)
    and on the quadric coefficients (``curvature_prior``, 1/m), i.e. ridge terms
    lambda = sigma^2 / prior^2 with sigma the neighbours' robust residual scale. The slope prior
    matters where the neighbours lie to one side of the vertex (the data's outline), where an
    unregularised fit extrapolates its noise. Residuals beyond 3 x 1.4826 x MAD are dropped and
    the fit is repeated once."""
    tree = tree or cKDTree(points[:, :2])
    k = int(min(max_neighbors, len(points)))
    dist, idx = tree.query(xy, k=k, distance_upper_bound=radius_m)
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    valid = idx < len(points)
    idx = np.where(valid, idx, 0)
    nb = points[idx]
    dx = nb[..., 0] - xy[:, None, 0]
    dy = nb[..., 1] - xy[:, None, 1]
    zz = nb[..., 2]
    cols = [np.ones_like(dx), dx, dy]
    if curvature_prior > 0:
        cols += [dx * dx, dx * dy, dy * dy]
    a = np.stack(cols, axis=-1)
    ncol = a.shape[-1]
    w = valid.astype(np.float64)
    with warnings.catch_warnings():  # rows without neighbours: NaN, dropped below
        warnings.simplefilter("ignore", RuntimeWarning)
        zmed = np.nanmedian(np.where(valid, zz, np.nan), axis=1)
    ridge = np.zeros((len(xy), ncol))
    z = np.full(len(xy), np.nan)
    for _ in range(2):
        ata = np.einsum("qk,qki,qkj->qij", w, a, a)
        diag = np.arange(ncol)
        # A tiny relative ridge keeps degenerate neighbourhoods (collinear points) solvable.
        eps = 1e-9 * np.maximum(np.einsum("qii->qi", ata)[:, 1:].max(axis=1), 1e-30)
        ata[:, diag[1:], diag[1:]] += ridge[:, 1:] + eps[:, None]
        atb = np.einsum("qk,qki,qk->qi", w, a, zz)
        n = w.sum(1)
        ok = n >= 3
        coef = np.zeros((len(xy), ncol))
        coef[:, 0] = zmed
        if ok.any():
            coef[ok] = np.linalg.solve(ata[ok], atb[ok][..., None])[..., 0]
        z = coef[:, 0]
        res = zz - np.einsum("qki,qi->qk", a, coef)
        r = np.where(w > 0, np.abs(res), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mad = np.nan_to_num(np.nanmedian(r, axis=1))
        thr = np.maximum(3.0 * 1.4826 * mad, 1e-6)
        sig2 = (1.4826 * mad) ** 2
        if slope_prior > 0:
            ridge[:, 1:3] = (sig2 / slope_prior**2)[:, None]
        if curvature_prior > 0:
            ridge[:, 3:] = (sig2 / curvature_prior**2)[:, None]
        w = (valid & (np.abs(res) <= thr[:, None])).astype(np.float64)
    n_used = w.sum(1)
    z = np.where(valid.sum(1) >= min_points, z, np.nan)
    return z, n_used


def surface_mesh(points: np.ndarray, voxel_m: float, k_edge: float, radius_m: float, max_neighbors: int,
                 min_points: int, slope_prior: float = 0.0,
                 curvature_prior: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Aligned (Z-up) road points -> (V, 3) vertices and (F, 3) triangles."""
    xy = xy_voxel_vertices(points, voxel_m)
    z, _ = local_heights(points, xy, radius_m, max_neighbors, min_points, slope_prior=slope_prior,
                         curvature_prior=curvature_prior)
    keep = np.isfinite(z)
    xy, z = xy[keep], z[keep]
    faces = delaunay_trimmed(xy, k_edge)
    used = np.unique(faces)
    remap = np.full(len(xy), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    if len(faces) == 0:
        raise RoadtwinError("surface: no triangles left after long-edge trimming")
    return np.column_stack([xy[used], z[used]]), remap[faces]
