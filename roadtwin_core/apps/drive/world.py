"""What sensors see of the town: the renderer plugin for cameras, a ray caster for LiDAR, the
labels of both (the render mesh's classes and defect instances)."""
from __future__ import annotations

import dataclasses

import numpy as np

from ...errors import RoadtwinError


class World:
    def __init__(self, render_mesh, renderer, render_params) -> None:
        self.mesh = render_mesh
        self.renderer = renderer
        self.render_params = dataclasses.replace(render_params, shade=True)
        self.class_names = list(render_mesh.classes)
        self.instances = {i["id"]: i["defect_id"] for i in render_mesh.instances}
        self._prepared = None
        self._rays = None
        self.origin = np.floor((render_mesh.vertices.min(0) + render_mesh.vertices.max(0)) / 2)
        self.renders = 0

    # cameras -------------------------------------------------------------------------------
    def render(self, cameras):
        if self._prepared is None:
            self._prepared = self.renderer.prepare(self.mesh, self.render_params)
        self.renders += len(cameras)
        return list(self.renderer.render(self._prepared, cameras, self.render_params))

    # LiDAR ----------------------------------------------------------------------------------
    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict:
        """Hit distance (inf: none), class id and defect instance (0: none) along unit rays."""
        try:
            import open3d as o3d
        except ImportError as exc:
            raise RoadtwinError(f"lidar: needs open3d ({exc})") from None
        if self._rays is None:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(self.mesh.vertices - self.origin, np.float32)),
                                o3d.core.Tensor(np.ascontiguousarray(self.mesh.faces, np.uint32)))
            self._rays = scene
        rays = np.ascontiguousarray(np.hstack([origins - self.origin, dirs]), np.float32)
        ans = self._rays.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy().astype(np.float64)
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        ok = np.isfinite(t) & (prim >= 0) & (prim < len(self.mesh.faces))
        cls = np.zeros(len(t), np.int32)
        inst = np.zeros(len(t), np.int32)
        cls[ok] = self.mesh.face_class[prim[ok]]
        inst[ok] = self.mesh.face_instance[prim[ok]]
        return {"t": np.where(ok, t, np.inf), "class_id": cls, "instance": inst}
