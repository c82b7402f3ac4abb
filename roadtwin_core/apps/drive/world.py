"""What sensors see of the town: the renderer plugin for cameras, a ray caster for LiDAR, the
labels of both (the render mesh's classes and defect instances).

The LiDAR's ray caster: open3d's (Embree) on the CPU, where it is several times faster than
warp's scalar CPU traversal; warp's ``mesh_query_ray`` on a CUDA device (the renderer's
``--param device=cuda``) or where open3d is missing (the GPU machine has no open3d).
Other vehicles (``--traffic``, :mod:`.traffic`) are drawn into both at ``time``, the sample's
time that the drive sets before each sample."""
from __future__ import annotations

import dataclasses

import numpy as np

from ...errors import RoadtwinError
from ...render import StereoCamera
from ...warp_runtime import start_warp, warp_device
from .traffic import ray_boxes, shade

_WARP_KERNEL = None


class World:
    expose_on_any_device = False       # tests: cameras developed by the renderer on a CPU device too (exposes)

    def __init__(self, render_mesh, renderer, render_params) -> None:
        self.mesh = render_mesh
        self.renderer = renderer
        self.source_params = render_params
        self.render_params = dataclasses.replace(render_params, shade=True)
        self.class_names = list(render_mesh.classes)
        self.instances = {i["id"]: i["defect_id"] for i in render_mesh.instances}
        self._prepared = None
        self._rays = None
        self.origin = np.floor((render_mesh.vertices.min(0) + render_mesh.vertices.max(0)) / 2)
        self.renders = 0
        self.traffic = None
        self.time = 0.0

    def set_traffic(self, traffic) -> None:
        """Draw ``traffic`` (or nothing: None) from now on: class ``vehicle`` (added to the
        classes if the town has none), instance ids after the town's, named ``vehicle_K``."""
        self.class_names = list(self.mesh.classes)
        self.instances = {i["id"]: i["defect_id"] for i in self.mesh.instances}
        self.traffic = traffic if traffic is not None and len(traffic) else None
        if self.traffic is None:
            return
        if "vehicle" not in self.class_names:
            self.class_names.append("vehicle")
        self.vehicle_class = self.class_names.index("vehicle")
        first = max([0, *self.instances]) + 1
        self.vehicle_instances = [first + k for k in range(len(self.traffic))]
        self.instances.update({i: f"vehicle_{k}" for k, i in enumerate(self.vehicle_instances)})

    def ground_z(self, xy) -> float:
        """The town's height under ``xy`` (a ray cast down through the mesh; 0 where none)."""
        top = float(self.mesh.vertices[:, 2].max()) + 10.0
        hit = self._mesh_cast(np.array([[xy[0], xy[1], top]]), np.array([[0.0, 0.0, -1.0]]))
        return top - float(hit[0][0]) if np.isfinite(hit[0][0]) else 0.0

    def prepare(self, render: bool, cast: bool) -> None:
        """Build now what the first frame (``render``: the renderer's scene, its BVH and textures)
        and the first LiDAR scan (``cast``: the ray caster's BVH) would: once a stage, so that it
        counts as loading, not as the first sample (a short drive's sensor time, extrapolated
        to a long one, would carry it a hundred times)."""
        if render and self.renderer is not None and self._prepared is None:
            self._prepared = self.renderer.prepare(self.mesh, self.render_params)
        if cast and self._rays is None:
            self._rays = self._ray_caster()

    # cameras -------------------------------------------------------------------------------
    def render(self, cameras):
        if self._prepared is None:
            self._prepared = self.renderer.prepare(self.mesh, self.render_params)
        self.renders += len(cameras)
        if self.traffic is None:
            return list(self.renderer.render(self._prepared, cameras, self.render_params))
        boxes = self.traffic.boxes(self.time)
        frames = []
        for cam in cameras:
            eyes = [cam.left, cam.right] if isinstance(cam, StereoCamera) else [cam]
            shots = list(self.renderer.render(self._prepared, eyes, self.render_params))
            for shot, eye in zip(shots, eyes):
                self._draw_vehicles(shot, eye, boxes)
            if len(shots) == 2:
                shots[0].rgb_right, shots[0].right_camera = shots[1].rgb, eyes[1]
            frames.append(shots[0])
        return frames

    def exposes(self) -> bool:
        """Whether cameras are developed where they render (:meth:`exposed`): a renderer with
        ``render_exposed`` (the warp renderer's) on a CUDA device, and no vehicles to draw (they
        are drawn on the host, before the blur)."""
        if self.traffic is not None or not hasattr(self.renderer, "render_exposed"):
            return False
        if self._prepared is None:
            self._prepared = self.renderer.prepare(self.mesh, self.render_params)
        return self.expose_on_any_device or str(getattr(self._prepared, "device", "")).startswith("cuda")

    def exposed(self, requests: list[dict]) -> list[dict]:
        """Camera exposures developed by the renderer (see the warp renderer's ``render_exposed``)."""
        self.renders += len(requests)
        return self.renderer.render_exposed(self._prepared, requests, self.render_params, any_device=True)

    def _draw_vehicles(self, frame, camera, boxes) -> None:
        """The vehicles in front of the town, z-buffered against the frame's depth."""
        dirs, origin = camera.rays()
        h, w = dirs.shape[:2]
        flat = dirs.reshape(-1, 3)
        t, which, normal = ray_boxes(np.broadcast_to(origin, flat.shape), flat, boxes)
        z = t * (flat @ camera.rotation[:, 2])
        depth = frame.depth.reshape(-1).astype(np.float64)
        front = (which >= 0) & ((depth <= 0) | ~np.isfinite(depth) | (z < depth))
        if not front.any():
            return
        colours = np.array([self.traffic.vehicles[k].colour for k in range(len(boxes))], np.float32)
        rgb = frame.rgb.reshape(-1, 3).copy()
        rgb[front] = shade(normal[front], (1.0, 1.0, 1.0)) * colours[which[front]]
        depth[front] = z[front]
        semantic, instance = frame.semantic.reshape(-1).copy(), frame.instance.reshape(-1).copy()
        semantic[front] = self.vehicle_class
        instance[front] = np.asarray(self.vehicle_instances)[which[front]]
        frame.rgb, frame.depth = rgb.reshape(h, w, 3), depth.reshape(h, w).astype(frame.depth.dtype)
        frame.semantic, frame.instance = semantic.reshape(h, w), instance.reshape(h, w)

    # LiDAR ----------------------------------------------------------------------------------
    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict:
        """Hit distance (inf: none), class id and defect instance (0: none) along unit rays."""
        t, prim = self._mesh_cast(origins, dirs)
        ok = np.isfinite(t)
        cls = np.zeros(len(t), np.int32)
        inst = np.zeros(len(t), np.int32)
        cls[ok] = self.mesh.face_class[prim[ok]]
        inst[ok] = self.mesh.face_instance[prim[ok]]
        if self.traffic is not None:
            tb, which, _ = ray_boxes(np.asarray(origins, np.float64), np.asarray(dirs, np.float64),
                                     self.traffic.boxes(self.time))
            front = (which >= 0) & (tb < t)
            t[front], cls[front] = tb[front], self.vehicle_class
            inst[front] = np.asarray(self.vehicle_instances)[which[front]]
        return {"t": t, "class_id": cls, "instance": inst}

    def _mesh_cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, face) along unit rays through the town (inf, -1: none)."""
        if self._rays is None:
            self._rays = self._ray_caster()
        t, prim = self._rays(np.ascontiguousarray(origins - self.origin, np.float32),
                             np.ascontiguousarray(dirs, np.float32))
        ok = np.isfinite(t) & (t >= 0) & (prim >= 0) & (prim < len(self.mesh.faces))
        return np.where(ok, t, np.inf), np.where(ok, prim, -1)

    def _ray_caster(self):
        """``cast(origins, dirs) -> (t, face)`` over the mesh (shifted to ``origin``)."""
        device = self.render_params.device or "cpu"
        vertices = np.ascontiguousarray(self.mesh.vertices - self.origin, np.float32)
        faces = np.ascontiguousarray(self.mesh.faces, np.int32)
        if device == "cpu":
            try:
                import open3d as o3d
            except ImportError:
                o3d = None
            if o3d is not None:
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(faces.astype(np.uint32)))

                def cast_open3d(o, d):
                    ans = scene.cast_rays(o3d.core.Tensor(np.hstack([o, d])))
                    return ans["t_hit"].numpy().astype(np.float64), ans["primitive_ids"].numpy().astype(np.int64)
                return cast_open3d
        return _warp_caster(vertices, faces, device)


def _warp_caster(vertices: np.ndarray, faces: np.ndarray, device: str):
    try:
        wp, dev = start_warp(), warp_device(device)
    except Exception as exc:
        raise RoadtwinError(f"lidar: no ray caster on device {device!r} ({str(exc).splitlines()[0]})") from None
    mesh = wp.Mesh(points=wp.array(vertices, dtype=wp.vec3, device=dev),
                   indices=wp.array(faces.reshape(-1), dtype=wp.int32, device=dev))
    kernel = _warp_kernel(wp)

    def cast_warp(o, d):
        n = len(o)
        t = wp.zeros(n, dtype=float, device=dev)
        face = wp.zeros(n, dtype=wp.int32, device=dev)
        if n:
            wp.launch(kernel, dim=n, device=dev, inputs=[mesh.id, wp.array(o, dtype=wp.vec3, device=dev),
                                                         wp.array(d, dtype=wp.vec3, device=dev), 1.0e4],
                      outputs=[t, face])
        return t.numpy().astype(np.float64), face.numpy().astype(np.int64)
    cast_warp.mesh = mesh                    # keep the BVH alive with the closure
    return cast_warp


def _warp_kernel(wp):
    """The ray-cast kernel, defined once warp is started (warp is an optional package)."""
    global _WARP_KERNEL
    if _WARP_KERNEL is None:
        @wp.kernel
        def lidar_cast(mesh: wp.uint64, origins: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                       max_t: float, t_out: wp.array(dtype=float), face_out: wp.array(dtype=wp.int32)):
            i = wp.tid()
            q = wp.mesh_query_ray(mesh, origins[i], dirs[i], max_t)
            if q.result:
                t_out[i] = q.t
                face_out[i] = q.face
            else:
                t_out[i] = -1.0
                face_out[i] = -1

        _WARP_KERNEL = lidar_cast
    return _WARP_KERNEL
