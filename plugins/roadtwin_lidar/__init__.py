"""Coarse stream of the hierarchical road model creator: LiDAR road surface reconstruction.

Registers the reconstructor ``lidar_surface`` (produces ``"surface"``). The kernels are core-free
apart from :class:`~roadtwin_core.RoadtwinError` and, for the simulator's ground truth,
:func:`~roadtwin_core.iso8608_surface` (numpy / scipy / open3d):

- :mod:`.reconstruct` -- frames + poses -> fused road points -> RANSAC ground plane to Z-up ->
  XY voxel downsample -> trimmed Delaunay -> robust local-plane elevation per vertex;
- :mod:`.simulate` -- the ISO 8608 + pothole ground truth for tests and bench, and how a
  reconstruction is scored against it (the rosette scan simulator that scans it is a sensor
  model: ``roadtwin_sensors.simulate_scans``).

Inputs of ``reconstruct(inputs, params)`` (a dict): ``frames`` (paths, or (N, 3) arrays),
``poses`` (a KITTI / TUM pose file path, or an (F, 4, 4) array; omitted with one frame = world
coordinates), ``labels`` (optional per-frame label arrays for array frames), ``road_labels``
(label values kept as road; default 40, 44 = SemanticKITTI road, parking; frames without labels
are all road), ``masks`` (optional: one road mask per frame, PNG paths or (H, W) arrays, non-zero =
road, e.g. Grounded-SAM's road/pavement output) with ``K`` (fx, fy, cx, cy or 3x3) and
``cam_from_lidar`` (4x4 array or text file; one for all frames): each frame's sensor-frame points
are projected into its mask and kept where they land on road (behind the camera or outside the
image: dropped; with labels too, a point must pass both); a frame left with no road point is a
:class:`~roadtwin_core.RoadtwinError` naming the frame and mask. ``source`` is recorded on the asset.

The result is a :class:`LidarSurface` (a :class:`~roadtwin_core.SurfaceModel`): a Z-up mesh in
meters in the ground-aligned frame, plus the 4x4 ``alignment`` (input world -> surface frame).
:func:`write_surface_asset` writes it as a library asset (kind ``component``, label
``road_surface``, ``roadtwin:source``, ``roadtwin:surface:alignment``); :func:`read_surface_asset`
reads it back.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from roadtwin_core import RoadtwinError, SampledSurface, SurfaceModel, check_params, field, hookimpl
from roadtwin_core.atomic import atomic_files
from roadtwin_core.render import camera_matrix
from roadtwin_core.usd import apply_labels, new_stage, read_mesh, safe_prim_name, set_attrs, set_kind, write_mesh

from .reconstruct import (apply, check_points, fuse_frames, ground_alignment, load_extrinsic, load_frame, load_mask,
                          load_poses, local_heights, mask_road_points, surface_mesh)
from .simulate import _raycasting_scene, _vertical_heights, pothole_road_mesh, save_frames

__all__ = ["LidarSurfaceReconstructor", "LidarSurface", "LidarSurfaceParams", "apply",
           "fuse_frames", "ground_alignment", "load_extrinsic", "load_frame", "load_mask", "load_poses",
           "local_heights", "mask_road_points", "pothole_road_mesh", "read_surface_asset", "save_frames",
           "surface_mesh", "write_surface_asset"]

DEFAULT_ROAD_LABELS = (40, 44)


@dataclass
class LidarSurfaceParams:
    voxel_m: float = field(0.05, lo=1e-3, hi=10.0, doc="XY voxel size of the downsample = mesh vertex spacing (m)")
    radius_m: float = field(0.08, lo=1e-3, hi=10.0, doc="neighbourhood radius of the per-vertex elevation fit (m)")
    max_neighbors: int = field(256, lo=3, hi=4096, doc="at most this many nearest points in the elevation fit")
    min_points: int = field(20, lo=3, hi=4096, doc="vertices with fewer points within radius_m are dropped")
    edge_factor: float = field(3.0, lo=1.0, hi=100.0, doc="drop triangles with an edge > edge_factor x median edge")
    plane_distance_m: float = field(0.05, lo=1e-4, hi=10.0, doc="RANSAC ground plane inlier distance (m)")
    max_plane_offset_m: float = field(1.0, lo=1e-3, doc="drop points farther than this from the ground plane (m)")
    slope_prior: float = field(0.1, lo=0.0, hi=100.0, doc="ridge prior (std) on local plane slopes; 0 = none")
    curvature_prior: float = field(0.0, lo=0.0, hi=1e6, doc="prior (std, 1/m) on quadric terms; 0 = plane fit")
    align: bool = True  # rotate the RANSAC plane to Z-up (False: keep the input world frame)
    seed: int = 0


class LidarSurface(SurfaceModel):
    """A reconstructed Z-up road surface mesh; ``height(xy)`` is exact on the mesh (vertical
    rays) and a local plane fit of the vertices outside it."""

    name = "lidar_surface"

    def __init__(self, name: str, vertices: np.ndarray, faces: np.ndarray, alignment: np.ndarray,
                 source: str = "", params: dict | None = None) -> None:
        self.name = name
        self.vertices = np.asarray(vertices, np.float64)
        self.faces = np.asarray(faces, np.int64)
        self.alignment = np.asarray(alignment, np.float64)
        self.source = source
        self.params = params or {}
        self._scene = None
        self._sampled = None

    def height(self, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(np.asarray(xy, np.float64))
        if self._scene is None:
            self._scene = _raycasting_scene(self.vertices, self.faces)
        z = _vertical_heights(self._scene, xy, top=float(self.vertices[:, 2].max()) + 10.0)
        miss = ~np.isfinite(z)
        if miss.any():
            if self._sampled is None:
                self._sampled = SampledSurface(self.vertices)
            z[miss] = self._sampled.height(xy[miss])
        return z

    def world_vertices(self) -> np.ndarray:
        """Vertices mapped back to the input world frame."""
        return apply(np.linalg.inv(self.alignment), self.vertices)


def _apply_masks(frames, names, masks, K, cam_from_lidar, who: str):
    """Keep the points of each frame that project onto road pixels of its mask."""
    if len(masks) != len(frames):
        raise RoadtwinError(f"{who}: {len(masks)} masks for {len(frames)} frames (one mask per frame)")
    if K is None:
        raise RoadtwinError(f"{who}: semantic masks need the camera intrinsics K (fx, fy, cx, cy)")
    if cam_from_lidar is None:
        raise RoadtwinError(f"{who}: semantic masks need the camera-from-LiDAR extrinsic (4x4)")
    Km = camera_matrix(K, "K")
    T = load_extrinsic(cam_from_lidar)
    out = []
    for i, ((pts, lab), name, m) in enumerate(zip(frames, names, masks)):
        mask, mname = load_mask(m, f"mask {i}")
        keep = mask_road_points(pts, mask, Km, T)
        if not keep.any():
            raise RoadtwinError(f"{name}: no road points: none of its {len(pts)} points projects onto a road "
                                f"pixel of {mname} (check the mask, K, the extrinsic and the frame order)")
        out.append((pts[keep], None if lab is None else lab[keep]))
    return out


class LidarSurfaceReconstructor:
    name = "lidar_surface"
    description = "LiDAR frames + poses -> road surface mesh (RANSAC ground plane, trimmed Delaunay, robust elevation)"
    produces = "surface"
    Params = LidarSurfaceParams

    def run(self, inputs: dict[str, Any], params: LidarSurfaceParams | None = None) -> LidarSurface:
        p = check_params(params or LidarSurfaceParams(), self.name)
        frames_in = list(inputs.get("frames") or [])
        if not frames_in:
            raise RoadtwinError(f"{self.name}: no point cloud frames given")
        labels_in = inputs.get("labels")
        frames, names = [], []
        for i, f in enumerate(frames_in):
            if isinstance(f, np.ndarray):
                name = f"frame {i}"
                lab = None if labels_in is None else np.asarray(labels_in[i]).ravel()
                frames.append(check_points(np.asarray(f, np.float64), lab, name))
            else:
                name = str(f)
                frames.append(load_frame(f))
            names.append(name)
        masks_in = inputs.get("masks")
        if masks_in is not None:
            frames = _apply_masks(frames, names, list(masks_in), inputs.get("K"), inputs.get("cam_from_lidar"),
                                  self.name)
        poses_in = inputs.get("poses")
        poses_name = "poses"
        if poses_in is None:
            poses = None
        elif isinstance(poses_in, np.ndarray):
            poses = np.asarray(poses_in, np.float64).reshape(-1, 4, 4)
        else:
            poses_name = str(poses_in)
            poses = load_poses(poses_in)
        road_labels = inputs.get("road_labels", DEFAULT_ROAD_LABELS)
        road_labels = None if road_labels is None else tuple(int(v) for v in road_labels)
        pts = fuse_frames(frames, poses, names, road_labels, poses_name)
        source = str(inputs.get("source") or (names[0] if len(names) == 1 else f"{names[0]} (+{len(names) - 1} frames)"))
        try:  # what goes wrong from here on is the data's: name the input it came from
            if len(pts) < 3:
                raise RoadtwinError(f"only {len(pts)} road points")
            T = ground_alignment(pts, p.plane_distance_m, p.seed) if p.align else np.eye(4)
            al = apply(T, pts)
            if p.align:
                al = al[np.abs(al[:, 2]) <= p.max_plane_offset_m]
            verts, faces = surface_mesh(al, p.voxel_m, p.edge_factor, p.radius_m, p.max_neighbors, p.min_points,
                                       p.slope_prior, p.curvature_prior)
        except RoadtwinError as exc:
            raise RoadtwinError(f"{source}: {exc}") from None
        except RuntimeError as exc:  # open3d refuses extents its voxel grid cannot index
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise RoadtwinError(f"{source}: cannot build the surface ({first})") from None
        stem = "lidar" if isinstance(frames_in[0], np.ndarray) else safe_prim_name(Path(names[0]).stem, empty="surface",
                                                                                   lead="s")
        return LidarSurface(f"{stem}_surface", verts, faces, T, source,
                            {"reconstructor": self.name, "frames": len(frames), "points": int(len(pts)),
                             "voxel_m": p.voxel_m, "radius_m": p.radius_m})

    def reconstruct(self, inputs: dict[str, Any], params: LidarSurfaceParams | None = None) -> list[LidarSurface]:
        return [self.run(inputs, params)]

    def write(self, surface: LidarSurface, out: str | Path) -> Path:
        return write_surface_asset(surface, out)


def write_surface_asset(surface: LidarSurface, path: str | Path) -> Path:
    """One self-contained library asset: ``/<name>`` (Xform, kind component, label
    ``road_surface``, ``roadtwin:source``, ``roadtwin:surface:*``) over ``/<name>/mesh``.
    Written beside the target and renamed, so a failure leaves nothing."""
    path = Path(path)
    name = safe_prim_name(surface.name, empty="surface", lead="s")
    with atomic_files(path) as (tmp,):
        stage = new_stage(tmp, name, f"roadtwin surface asset: {name}")
        root = UsdGeom.Xform.Define(stage, f"/{name}").GetPrim()
        set_kind(root, "component")
        apply_labels(root, ["road_surface"])
        set_attrs(root, "roadtwin", {"source": surface.source,
                                     "params": json.dumps(surface.params, sort_keys=True)})
        root.CreateAttribute("roadtwin:surface:alignment", Sdf.ValueTypeNames.Matrix4d, custom=True).Set(
            # USD matrices are row-vector (p' = p M): store the transpose of our column-vector T.
            Gf.Matrix4d(surface.alignment.T.tolist()))
        set_attrs(root, "roadtwin:surface", {"vertexCount": int(len(surface.vertices)),
                                             "faceCount": int(len(surface.faces))})
        mesh = UsdGeom.Mesh.Define(stage, f"/{name}/mesh")
        write_mesh(mesh, surface.vertices, surface.faces)
        lo, hi = surface.vertices.min(axis=0), surface.vertices.max(axis=0)
        UsdGeom.ModelAPI(root).SetExtentsHint(Vt.Vec3fArray([tuple(lo.tolist()), tuple(hi.tolist())]))
        stage.GetRootLayer().Save()
        del stage
    return path


def read_surface_asset(path: str | Path) -> LidarSurface:
    """A surface asset written by :func:`write_surface_asset` (or any asset whose default prim
    holds one triangle mesh) as a :class:`LidarSurface`."""
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such surface asset")
    stage = Usd.Stage.Open(str(path))
    root = stage.GetDefaultPrim()
    if not root:
        raise RoadtwinError(f"{path}: surface asset has no defaultPrim")
    mesh_prim = next((q for q in Usd.PrimRange(root) if q.IsA(UsdGeom.Mesh)), None)
    if mesh_prim is None:
        raise RoadtwinError(f"{path}: surface asset has no mesh")
    pts, faces = read_mesh(UsdGeom.Mesh(mesh_prim), world=True)
    al = root.GetAttribute("roadtwin:surface:alignment")
    T = np.asarray(al.Get(), np.float64).T if al and al.Get() is not None else np.eye(4)
    src = root.GetAttribute("roadtwin:source")
    return LidarSurface(root.GetName(), pts, faces, T, str(src.Get()) if src else path.name)


@hookimpl
def roadtwin_register_reconstructors(register):
    register(LidarSurfaceReconstructor())
