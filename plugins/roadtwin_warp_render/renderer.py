"""The ``warp`` renderer: roadtwin cameras and scenes in, :class:`Frame` objects out.

All ray casting and shading runs in the kernels of ``raycast.py`` (numpy + warp); what a
surface looks like comes from the stage (``RenderMesh.materials``: the bound UsdPreviewSurface
materials and their textures), never from code here. On a CPU
device the primary (G-buffer) rays may instead go through open3d's RaycastingScene (Embree),
which is about twice as fast as warp's scalar CPU traversal, and so do the sun's shadow rays
then (the same rays, Embree's answers); shading and stereo occlusion stay in warp either way
(``backend``: auto = open3d on CPU when installed, warp otherwise). The town is shifted to a local origin before it goes to float32 device memory, so
geo-referenced coordinates keep millimetre precision. warp is imported on first use, so listing
plugins does not load it.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import numpy as np

from roadtwin_core import RoadtwinError, check_params
from roadtwin_core.warp_runtime import start_warp, warp_device
from roadtwin_core.render import (Camera, Frame, RenderMesh, RenderParams, StereoCamera, WEATHERS,
                                  build_render_mesh)


def _rc():
    """The kernels module, warp started quietly (no banner, module-load lines or CUDA notice)."""
    start_warp()
    from . import raycast

    return raycast


@dataclass
class PreparedScene:
    """A scene uploaded to a device, reusable across render calls."""

    mesh: RenderMesh
    origin: np.ndarray
    rs: object               # raycast.RaycastScene
    device: str
    backend: str


class WarpRenderer:
    name = "warp"
    description = ("ray-cast renderer on warp (CPU/CUDA): depth, normals, classes, instances, stereo "
                   "disparity with occlusion, RGB from the stage's UsdPreviewSurface materials and textures "
                   "with sun, shadows, fog, wet road, dusk")
    Params = RenderParams

    # ------------------------------------------------------------------ scene
    def prepare(self, scene, params: RenderParams | None = None) -> PreparedScene:
        if isinstance(scene, PreparedScene):
            return scene
        params = check_params(params or RenderParams(), "renderer warp")
        mesh = scene if isinstance(scene, RenderMesh) else build_render_mesh(scene)
        rc = _rc()
        try:
            device = str(warp_device(params.device))
        except Exception as exc:
            raise RoadtwinError(f"renderer warp: no device {params.device!r} ({exc})") from None
        backend = params.backend
        if backend not in ("auto", "warp", "open3d"):
            raise RoadtwinError(f"renderer warp: unknown backend {backend!r} (known: auto, warp, open3d)")
        if backend == "auto":
            backend = "open3d" if device == "cpu" and _has_open3d() else "warp"
        if backend == "open3d" and device != "cpu":
            raise RoadtwinError("renderer warp: the open3d backend runs on the CPU only (use --device cpu)")
        lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
        origin = np.floor((lo + hi) / 2.0)
        local = mesh.vertices - origin
        rs = rc.RaycastScene(local, mesh.faces, mesh.face_class, mesh.face_instance, mesh.face_material,
                             mesh.face_uv, [m.as_dict() for m in mesh.materials], device=device,
                             background_class=0)
        rs.max_t = float(params.max_distance_m)
        if backend == "open3d":
            rs.enable_open3d()
        return PreparedScene(mesh, origin, rs, device, backend)

    # ------------------------------------------------------------------ checks
    def check_cameras(self, prepared: PreparedScene, cameras: Sequence, params: RenderParams) -> None:
        """A camera inside geometry (a surface nearer than ``min_clearance_m`` along the optical
        axis, the image corners or straight down) or under the road (the ray straight up meets
        the back of a surface) is an error naming the camera."""
        origins, dirs, owner = [], [], []
        for k, cam in enumerate(cameras):
            views = [cam.left, cam.right] if isinstance(cam, StereoCamera) else [cam]
            for view in views:
                if not isinstance(view, Camera):
                    raise RoadtwinError(f"camera {k}: expected a Camera or StereoCamera, got {type(view).__name__}")
                ki = view.intrinsics
                r = view.rotation
                for u, v in ((ki.cx, ki.cy), (0, 0), (ki.width - 1, 0), (0, ki.height - 1),
                             (ki.width - 1, ki.height - 1)):
                    dirs.append(r @ np.array([(u - ki.cx) / ki.fx, (v - ki.cy) / ki.fy, 1.0]))
                dirs += [np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])]
                origins += [view.position - prepared.origin] * 7
                owner += [(k, view)] * 7
        if not origins:
            raise RoadtwinError("no cameras to render")
        t, sign = prepared.rs.cast(np.array(origins), np.array(dirs))
        for i in range(0, len(t), 7):
            k, view = owner[i]
            p = ", ".join(f"{x:.2f}" for x in view.position)
            ti, si = t[i:i + 7], sign[i:i + 7]
            hit = ti >= 0
            if hit.any() and ti[hit].min() < params.min_clearance_m:
                raise RoadtwinError(f"camera {k} at ({p}) is inside geometry: a surface {ti[hit].min():.3f} m away "
                                    f"(minimum clearance {params.min_clearance_m} m)")
            if hit[6] and si[6] < 0:
                raise RoadtwinError(f"camera {k} at ({p}) is below the road surface or inside geometry: "
                                    f"the back of a surface is {ti[6]:.2f} m above it")
            if hit.all() and (si < 0).all():
                raise RoadtwinError(f"camera {k} at ({p}) is inside geometry: it sees only the backs of surfaces")

    # ------------------------------------------------------------------ render
    def render(self, scene, cameras: Iterable, params: RenderParams | None = None, look=None) -> Iterator[Frame]:
        """Frames for ``cameras`` (Camera or StereoCamera), in order; all cameras are checked
        before the first frame is rendered. ``look``: a per-frame material look
        (:class:`roadtwin_core.render.scene_look.MaterialLook`: material remap, diffuse scale,
        sky tint) for these frames; None = the stage's materials as they are."""
        prepared, cameras, params, light, material_look = self._setup(scene, cameras, params, look)
        return self._frames(prepared, cameras, params, light, material_look)

    def render_events(self, scene, cameras: Sequence[Camera], times: Sequence[float],
                      params: RenderParams | None = None, progress=None, any_device: bool = False,
                      **camera) -> tuple[dict, dict] | None:
        """The event stream of a drive (``cameras`` at ``times``), simulated where the frames are:
        on a CUDA device each view is shaded and handed to the warp event camera in device memory
        (same events as ``roadtwin_core.render.EventSimulator``; ``camera``: its keyword
        arguments). Returns ``(events, simulator params)``, or None on a CPU device, where the
        caller runs the numpy reference on rendered frames (``any_device``: run it there too)."""
        params = dataclasses.replace(check_params(params or RenderParams(), "renderer warp"), shade=True)
        cameras = list(cameras)
        if not (any_device or self.prepare(scene, params).device.startswith("cuda")) or not cameras:
            return None
        prepared, cameras, params, light, material_look = self._setup(scene, cameras, params, None)
        from .event_kernels import WarpEventSimulator

        _rc().set_material_look(prepared.rs.textures, *material_look, prepared.rs.device)
        k = cameras[0].intrinsics
        sim = WarpEventSimulator(k.width, k.height, device=prepared.device, **camera)
        chunks = []
        for i, (cam, t) in enumerate(zip(cameras, times)):
            _c, gb = self._view(prepared, cam, params, light, slot=0)
            chunks.append(sim.step(gb.rgb, float(t)))
            if progress:
                progress(i + 1, len(cameras))
        return {key: np.concatenate([c[key] for c in chunks]) for key in ("x", "y", "t", "p")}, sim.params()

    def render_exposed(self, scene, exposures: Sequence[dict], params: RenderParams | None = None,
                       any_device: bool = False) -> list[dict] | None:
        """A drive camera's exposures developed on the device (``exposure.py``: motion blur by
        reprojection, tone curve, read noise; only 8-bit images travel). A request: ``camera`` (the
        middle sub-frame's, mono), ``subframes`` (each sub-frame's cam_to_world, in order),
        ``read_noise`` (DN), ``seed``, ``far_m`` (where sky pixels are put), ``labels`` (True: also
        depth, semantic, instance). Returns per request ``{"rgb8", ...}``, or None on a CPU device
        (unless ``any_device``): the caller develops on the host."""
        from .exposure import develop_exposure

        params = dataclasses.replace(check_params(params or RenderParams(), "renderer warp"), shade=True)
        if not (any_device or self.prepare(scene, params).device.startswith("cuda")):
            return None
        prepared, cams, params, light, material_look = self._setup(scene, [e["camera"] for e in exposures], params,
                                                                   None)
        _rc().set_material_look(prepared.rs.textures, *material_look, prepared.rs.device)
        out = []
        for e, cam in zip(exposures, cams):
            c, gb = self._view(prepared, cam, params, light, slot=0)
            res = {"rgb8": develop_exposure(gb, c, cam.cam_to_world, list(e["subframes"]), e["far_m"], e["read_noise"],
                                            e["seed"])}
            if e.get("labels"):
                g = gb.numpy(("depth", "dist", "cls", "inst", "face"))
                res.update(depth=g["depth"], semantic=_semantic(g, params), instance=g["inst"])
            out.append(res)
        return out

    def _setup(self, scene, cameras, params, look):
        params = check_params(params or RenderParams(), "renderer warp")
        if params.weather not in WEATHERS:
            raise RoadtwinError(f"unknown weather {params.weather!r} (known: {', '.join(WEATHERS)})")
        prepared = self.prepare(scene, params)
        cameras = list(cameras)
        self.check_cameras(prepared, cameras, params)
        return (prepared, cameras, params) + self._light_and_look(prepared, params, look)

    def _light_and_look(self, prepared, params, look):
        """The warp light of ``params`` (sky tinted by ``look``) and the material look (remap, scale)."""
        rc = _rc()
        spec = rc.light_preset(params.weather, sun_elevation_deg=params.sun_elevation_deg,
                               sun_azimuth_deg=params.sun_azimuth_deg, fog_density=params.fog_density,
                               wetness=params.wetness, shadows=params.shadows, seed=params.seed)
        n = len(prepared.mesh.materials)
        if look is not None:
            tint = np.asarray(look.sky_tint, np.float64)
            spec.sky_zenith = tuple(np.asarray(spec.sky_zenith) * tint)
            spec.sky_horizon = tuple(np.asarray(spec.sky_horizon) * tint)
            remap, scale = look.remap, look.albedo_scale
        else:
            remap, scale = np.arange(n), np.ones((n, 3))
        return rc.make_light(spec), (remap, scale)

    # ------------------------------------------------------------------ finished on the device
    def render_finished(self, scene, requests: Sequence[dict], params: RenderParams | None = None,
                        batch: int = 16) -> Iterator[dict]:
        """Frames finished where they are rendered (``post.py``): the camera model and the
        labels run as device kernels on batches of ``batch`` frames; one copy to the host a batch.
        A request: ``camera`` (mono), ``params``, ``look`` (or None), ``effects`` (``ImageEffects``
        or None: plain tone mapping), ``labels`` (label_distance, and with a class map its
        ``plain`` / ``inside`` tables, the ego ``lane`` (world XY), ``half_width``, ``s_cam``).
        Yields per request: rgb8, labels (uint8), depth, instance, exposure_scale. Same seed,
        same device: same bytes; other bytes than the CPU's camera model (other random numbers).
        Every camera is checked before the first frame renders. The next batch is queued on the
        device before this one's frames are handed out, so the GPU renders while the caller
        (and the host's share of the next batch) runs."""
        from .post import DeviceFinisher

        params = check_params(params or RenderParams(), "renderer warp")
        prepared = self.prepare(scene, params)
        requests = list(requests)
        if not requests:
            return
        k = requests[0]["camera"].intrinsics
        cams = [r["camera"] for r in requests]
        if any(isinstance(c, StereoCamera) or c.intrinsics != k for c in cams):
            raise RoadtwinError("renderer warp: frames finished on the device are mono, of one size")
        self.check_cameras(prepared, cams, params)
        finisher = DeviceFinisher(k.width, k.height, batch, prepared.device)
        parts = [requests[s:s + batch] for s in range(0, len(requests), batch)]
        self._queue_batch(prepared, finisher, self._batch_inputs(prepared, parts[0]))
        staged = self._batch_inputs(prepared, parts[1]) if len(parts) > 1 else None
        for i, part in enumerate(parts):
            out = finisher.collect()
            if staged is not None:
                self._queue_batch(prepared, finisher, staged)
            staged = self._batch_inputs(prepared, parts[i + 2]) if i + 2 < len(parts) else None
            for b in range(len(part)):
                yield {key: value[b] for key, value in out.items()}

    def _batch_inputs(self, prepared: PreparedScene, part: list[dict]) -> list[dict]:
        """The host's share of a batch's frames, before anything goes to the device: the camera,
        light, material look, sensor and labels of each."""
        from .post import make_sensor

        rc = _rc()
        n_materials = prepared.rs.textures.mat_diffuse.shape[0]
        frames = []
        for r in part:
            p = dataclasses.replace(check_params(r["params"], "renderer warp"), shade=True)
            light, (remap, scale) = self._light_and_look(prepared, p, r.get("look"))
            try:
                remap, scale = rc.checked_material_look(n_materials, remap, scale)
            except ValueError as exc:
                raise RoadtwinError(f"renderer warp: {exc}") from None
            labels = {"background": prepared.rs.background, "label_distance": p.label_distance_m, **r["labels"]}
            lane = labels.pop("lane", None)
            effects = r.get("effects")
            frames.append({"camera": r["camera"], "params": p, "light": light, "remap": remap, "scale": scale,
                           "labels": labels, "sensor": make_sensor(effects, r["camera"]),
                           "blur_px": float(getattr(effects, "blur_px", 0.0) or 0.0),
                           "lane": None if lane is None else np.asarray(lane, np.float64)[:, :2] - prepared.origin[:2]})
        return frames

    def _queue_batch(self, prepared: PreparedScene, finisher, frames: list[dict]) -> None:
        """A batch's small inputs up in one copy a kind, then every kernel of it and the copies
        back queued on the device (nothing here waits for the device)."""
        views = finisher.upload(frames)
        tex = prepared.rs.textures
        c = None
        for slot, (f, v) in enumerate(zip(frames, views)):
            tex.mat_remap, tex.mat_scale = v["remap"], v["scale"]
            c, gb = self._view(prepared, f["camera"], f["params"], f["light"], slot=0)
            finisher.frame(slot, c, gb, f["sensor"], f["blur_px"],
                           {**f["labels"], "lane": v["lane"], "blur_weights": v["blur_weights"]})
        finisher.launch_finish(c, [f["sensor"] for f in frames])

    def _frames(self, prepared, cameras, params, light, material_look) -> Iterator[Frame]:
        try:
            _rc().set_material_look(prepared.rs.textures, *material_look, prepared.rs.device)
        except ValueError as exc:
            raise RoadtwinError(f"renderer warp: {exc}") from None
        for k, cam in enumerate(cameras):
            stereo = isinstance(cam, StereoCamera)
            left = cam.left if stereo else cam
            c, gb = self._view(prepared, left, params, light, slot=0)
            if stereo:
                right = cam.right
                prepared.rs.stereo(c, right.position - prepared.origin, cam.baseline, gb)
            out = gb.numpy(("depth", "dist", "normal", "cls", "inst", "face"))
            frame = Frame(index=k, camera=left, depth=out["depth"], normal=out["normal"], semantic=_semantic(out, params),
                          instance=out["inst"], face=out["face"])
            if params.shade:
                frame.rgb = gb.numpy(("rgb",))["rgb"]
            if stereo:
                s = gb.numpy(("disparity", "occluded"))
                frame.disparity, frame.occluded = s["disparity"], s["occluded"].astype(bool)
                frame.right_camera = right
                if params.shade:
                    _, gbr = self._view(prepared, right, params, light, slot=1)
                    frame.rgb_right = gbr.numpy(("rgb",))["rgb"]
            yield frame

    def _view(self, prepared: PreparedScene, cam: Camera, params: RenderParams, light, slot: int):
        k = cam.intrinsics
        m = cam.cam_to_world.copy()
        m[:3, 3] -= prepared.origin
        c = _rc().make_cam(k.fx, k.fy, k.cx, k.cy, k.width, k.height, m)
        rs = prepared.rs
        gb = rs.buffer(k.width, k.height, slot)
        if prepared.backend == "open3d":
            rs.gbuffer_open3d(c, gb)
        else:
            rs.gbuffer(c, gb)
        if params.shade:
            rs.shade(c, light, gb)
        return c, gb


def _semantic(gbuffer: dict, params: RenderParams) -> np.ndarray:
    """Class ids of a G-buffer on the host; surfaces farther than the label distance: 255 (ignore)."""
    semantic = gbuffer["cls"].astype(np.uint8)
    semantic[(gbuffer["face"] >= 0) & (gbuffer["dist"] > params.label_distance_m)] = 255
    return semantic


def _has_open3d() -> bool:
    try:
        import open3d  # noqa: F401
    except Exception:
        return False
    return True
