"""Cameras (mono and a rectified stereo pair) rendered through the renderer the drive uses.

Exposure-time motion blur from the body's real motion: the frame is the mean of the images at
the camera's poses across the exposure (stamped at its middle), as many sub-frames as the image
moves pixels during it (the centre ray's and the image corners' motion, at most
``max_subframes``). ``blur = "reproject"`` (default) renders the middle sub-frame only (a pair
as two mono views) and moves it to each other sub-frame's pose through its own depth (the velocity-buffer blur of real-time
graphics: exact for a static scene but at occlusion edges, where a few pixels of motion reveal
what the middle frame hides): one render a frame instead of one a sub-frame, the renderer being
the drive's cost. ``blur = "render"`` renders every sub-frame. Labels, depth and instance ids are
the middle sub-frame's (odd counts). Sensor noise: Gaussian read noise on the tone-mapped image.
With ``reproject`` on a renderer that develops where it renders (the warp renderer on CUDA:
``World.exposes``), the blur, tone curve and noise run there and only 8-bit images come back
(the same model; other noise numbers, from a seed this camera's generator draws for each eye).
"""
from __future__ import annotations

import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from roadtwin_core import RoadtwinError, field
from roadtwin_core.render import Camera, Intrinsics, StereoCamera, to_srgb8

from ._mount import OPTICAL_IN_LINK, MountedSensor, SensorType

FAR_M = 1.0e4          # where pixels that hit nothing (sky) are put for the blur: they move with the rotation only


@dataclass
class CameraParams:
    width: int = field(640, lo=8, hi=8192, doc="image width, px")
    height: int = field(360, lo=8, hi=8192, doc="image height, px")
    hfov_deg: float = field(90.0, lo=1.0, hi=179.0, doc="horizontal field of view, degrees")
    exposure_s: float = field(0.008, lo=0.0, hi=0.1, doc="exposure time, s (0: no motion blur)")
    max_subframes: int = field(7, lo=1, hi=31, doc="most sub-frames averaged for motion blur")
    read_noise: float = field(1.0, lo=0.0, hi=50.0, doc="Gaussian noise on the 8-bit image, DN (1 sigma)")
    baseline_m: float = field(0.12, lo=0.01, hi=5.0, doc="stereo baseline, m (stereo only)")
    blur: str = field("reproject", doc="motion blur: reproject (render the middle sub-frame, move it through its "
                                       "depth) | render (render every sub-frame)")
    seed: int = field(0, lo=0, doc="noise seed (combined with the sensor's name)")


class CameraSensor(MountedSensor):
    message = "image"

    def __init__(self, sensor_id, rate_hz, extrinsic, params: CameraParams, stereo: bool = False) -> None:
        super().__init__(sensor_id, rate_hz, extrinsic, params)
        if params.exposure_s > 1.0 / self.rate_hz:
            raise RoadtwinError(f"sensor {sensor_id}: exposure {params.exposure_s} s is longer than the frame period "
                                f"{1.0 / self.rate_hz:.4f} s")
        if params.blur not in ("reproject", "render"):
            raise RoadtwinError(f"sensor {sensor_id}: blur must be reproject or render, got {params.blur!r}")
        self.stereo = stereo
        self.message = "stereo" if stereo else "image"
        self.intrinsics = Intrinsics.from_fov(int(params.width), int(params.height), params.hfov_deg)
        self.optical = np.eye(4)                    # optical frame in the body
        self.optical[:3, :3] = self.extrinsic[:3, :3] @ OPTICAL_IN_LINK
        self.optical[:3, 3] = self.extrinsic[:3, 3]

    def camera_at(self, state, t: float) -> Camera:
        return Camera(self.intrinsics, state.pose_at(t) @ self.optical)

    def _subframes(self, state) -> np.ndarray:
        p = self.params
        if p.exposure_s <= 0:
            return np.array([state.t])
        k = self.intrinsics
        a, b = self.camera_at(state, state.t - p.exposure_s / 2), self.camera_at(state, state.t + p.exposure_s / 2)
        # image motion of points 10 m out along the centre and corner rays
        rays = np.array([[0, 0, 1], [-k.cx / k.fx, -k.cy / k.fy, 1], [k.cx / k.fx, k.cy / k.fy, 1]], float)
        pts = a.position + 10.0 * (rays / np.linalg.norm(rays, axis=1, keepdims=True)) @ a.rotation.T
        ua, _ = a.project(pts)
        ub, _ = b.project(pts)
        move = float(np.nanmax(np.linalg.norm(ub - ua, axis=1)))
        n = int(min(p.max_subframes, max(1, math.ceil(move / 0.5) + 1)))
        n += (n + 1) % 2                               # odd: a middle sub-frame for the labels
        n = min(n, p.max_subframes if p.max_subframes % 2 else p.max_subframes - 1) or 1
        return state.t + (np.linspace(-0.5, 0.5, n) if n > 1 else np.zeros(1)) * p.exposure_s

    def sample(self, state, world) -> dict:
        p = self.params
        times = self._subframes(state)
        cams = [self.camera_at(state, t) for t in times]
        views = [StereoCamera(c, p.baseline_m) for c in cams] if self.stereo else cams
        mid_k = len(cams) // 2
        images = self._exposed_on_device(world, cams, views, mid_k) if p.blur == "reproject" else None
        if images is None:
            images = self._exposed_on_host(world, cams, views, mid_k)
        rgb, rgb_right, mid = images
        out = {"t": state.t, "intrinsics": self.intrinsics, "subframes": len(cams), "exposure_s": p.exposure_s,
               "cam_to_world": cams[mid_k].cam_to_world, "semantic": mid["semantic"], "instance": mid["instance"],
               "depth": mid["depth"], "rgb": rgb}
        if self.stereo:
            out["rgb_right"] = rgb_right
            out["baseline_m"] = p.baseline_m
        return out

    def _exposed_on_host(self, world, cams: list, views: list, mid_k: int) -> tuple:
        """(8-bit left image, right image or None, the middle frame's labels): rendered, blurred
        (``blur``: the sub-frames rendered, or the middle one reprojected) and developed here."""
        if self.params.blur == "render":
            frames = list(world.render(views))
            mid = frames[mid_k]
            left = exposure_mean([f.rgb for f in frames])
            right = exposure_mean([f.rgb_right for f in frames]) if self.stereo else None
        else:
            # the pair as two mono views: each eye's own depth moves it, and the renderer skips the
            # stereo occlusion pass that nobody here reads
            eyes = list(world.render([cams[mid_k], views[mid_k].right] if self.stereo else [cams[mid_k]]))
            mid = eyes[0]
            left = reproject_blur(mid.rgb, mid.depth, cams[mid_k], cams)
            right = reproject_blur(eyes[1].rgb, eyes[1].depth, views[mid_k].right, [v.right for v in views]) \
                if self.stereo else None
        labels = {"semantic": mid.semantic, "instance": mid.instance, "depth": mid.depth}
        return self._develop(left), (self._develop(right) if self.stereo else None), labels

    def _exposed_on_device(self, world, cams: list, views: list, mid_k: int) -> tuple | None:
        """As :meth:`_exposed_on_host` with the middle frames reprojected, developed by the
        renderer on its device (``World.exposed``: the same blur, tone curve and read noise, other
        noise numbers, from a seed this camera's generator draws for each eye), or None."""
        if not getattr(world, "exposes", lambda: False)():
            return None
        eyes = [(cams[mid_k], [c.cam_to_world for c in cams], True)]
        if self.stereo:
            eyes.append((views[mid_k].right, [v.right.cam_to_world for v in views], False))
        exposed = world.exposed([
            {"camera": cam, "subframes": subs, "labels": labels, "read_noise": self.params.read_noise, "far_m": FAR_M,
             "seed": int(self.rng.integers(2**31))} for cam, subs, labels in eyes])
        return exposed[0]["rgb8"], exposed[1]["rgb8"] if self.stereo else None, exposed[0]

    def _develop(self, linear: np.ndarray) -> np.ndarray:
        """The exposure's mean linear image -> 8-bit, with read noise. Element by element, so the
        tone curve and the rounding run in bands of rows on the blur's threads (the same bytes as
        one pass); the noise is drawn in one piece, in the generator's order."""
        noise = None
        if self.params.read_noise > 0:
            noise = self.rng.normal(0.0, self.params.read_noise, linear.shape).astype(np.float32)
        out = np.empty(linear.shape, np.uint8)

        def band(rows: slice) -> None:
            img = to_srgb8(linear[rows]).astype(np.float32)
            if noise is not None:
                img += noise[rows]
            np.round(img, out=img)
            np.clip(img, 0, 255, out=img)
            out[rows] = img.astype(np.uint8)

        h = linear.shape[0]
        step = max(1, -(-h // 16))
        list(_blur_pool().map(band, [slice(r, min(r + step, h)) for r in range(0, h, step)]))
        return out


def exposure_mean(images) -> np.ndarray:
    """The mean of the sub-frames' linear images, summed in place in their order (the same
    float32 sum, hence the same bytes, as ``np.mean(np.stack(images), axis=0)``, without the stack)."""
    acc = None
    for img in images:
        if acc is None:
            acc = np.array(img, dtype=np.float32)
        else:
            np.add(acc, img, out=acc)
    return _divide(acc, len(images))


def _divide(acc: np.ndarray, n: int) -> np.ndarray:
    # np.mean divides its float32 sum by an intp count (in float64, cast back): the same here
    np.true_divide(acc, np.intp(n), out=acc, casting="unsafe")
    return acc


def reproject_blur(rgb: np.ndarray, depth: np.ndarray, mid: Camera, cams: list[Camera]) -> np.ndarray:
    """The mean over ``cams`` of ``rgb`` (the view of camera ``mid``, z-depth ``depth``) as each of
    them sees it: pixel q of camera c looks at the point that its ray meets at the middle frame's
    depth of q, and takes the middle image's colour where that point projects (bilinear). The
    depth of q in c is the middle frame's: right for the few pixels that a blur moves, but at
    occlusion edges. The sub-frames are moved on a thread pool (numpy's and OpenCV's loops let
    go of the GIL; a 1280x720 pair's seven sub-frames were most of a drive's wall time on one
    core) into buffers kept across frames (fresh frame-sized arrays cost page faults every
    frame), then summed in their order: the same float32 sum, hence the same bytes, as one thread."""
    try:
        import cv2
    except ImportError as exc:
        raise RoadtwinError(f"camera motion blur: reproject needs opencv ({exc}); or set blur = \"render\"") from None
    k = mid.intrinsics
    z = np.where(np.isfinite(depth) & (depth > 0), depth, FAR_M).astype(np.float32)
    u = np.arange(k.width, dtype=np.float32)[None, :]
    v = np.arange(k.height, dtype=np.float32)[:, None]
    x, y = (u - np.float32(k.cx)) / np.float32(k.fx) * z, (v - np.float32(k.cy)) / np.float32(k.fy) * z
    src = np.ascontiguousarray(rgb, dtype=np.float32)
    is_moved = [not np.array_equal(c.cam_to_world, mid.cam_to_world) for c in cams]
    moved = [c for c, m in zip(cams, is_moved) if m]

    def move(c: Camera, shot: np.ndarray) -> np.ndarray:
        """``src`` as camera ``c`` sees it, into ``shot`` (buffers of this thread for the maps)."""
        maps, term, behind = _thread_buffers(z.shape)
        # camera c's point -> world -> the middle camera's frame: one rigid transform
        rel = (np.linalg.inv(mid.cam_to_world) @ c.cam_to_world).astype(np.float32)
        for i, m in enumerate(maps):       # m = rel[i, 0] x + rel[i, 1] y + rel[i, 2] z + rel[i, 3]
            np.multiply(rel[i, 0], x, out=m)
            for col, a in ((1, y), (2, z)):
                np.add(m, np.multiply(rel[i, col], a, out=term), out=m)
            np.add(m, rel[i, 3], out=m)
        map_x, map_y, zm = maps
        np.logical_not(np.greater(zm, np.float32(1e-6), out=behind), out=behind)
        zm[behind] = np.float32(1.0)
        for m, f, cc in ((map_x, k.fx, k.cx), (map_y, k.fy, k.cy)):
            np.multiply(np.float32(f), m, out=m)
            np.divide(m, zm, out=m)
            np.add(m, np.float32(cc), out=m)
            m[behind] = np.float32(-1.0)
        return cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, dst=shot, borderMode=cv2.BORDER_REPLICATE)

    with _BLUR_LOCK:                       # the shot buffers are shared by every call
        shots = _shot_buffers(src.shape, len(moved))
        views = _blur_pool().map(move, moved, shots) if len(moved) > 1 else map(move, moved, shots)
        acc = None
        for m in is_moved:
            view = next(views) if m else src
            if acc is None:
                acc = view.copy()
            else:
                np.add(acc, view, out=acc)
    return _divide(acc, len(cams))


_BLUR_LOCK = threading.Lock()
_BLUR_STATE: dict = {}


def _blur_pool() -> ThreadPoolExecutor:
    """Threads for the sub-frames (one a core, at most 8), made once a process (a forked child
    makes its own)."""
    pool = _BLUR_STATE.get("pool")
    if pool is None or _BLUR_STATE.get("pid") != os.getpid():
        pool = ThreadPoolExecutor(max(1, min(8, os.cpu_count() or 1)), thread_name_prefix="camera-blur")
        _BLUR_STATE.update(pool=pool, pid=os.getpid())
    return pool


def _shot_buffers(shape: tuple, n: int) -> list[np.ndarray]:
    """``n`` images of ``shape`` (float32), kept across calls."""
    shots = _BLUR_STATE.get("shots")
    if shots is None or shots[0].shape != shape or len(shots) < n or _BLUR_STATE.get("shots_pid") != os.getpid():
        shots = [np.empty(shape, np.float32) for _ in range(max(n, 1))]
        _BLUR_STATE.update(shots=shots, shots_pid=os.getpid())
    return shots[:n]


_THREAD = threading.local()


def _thread_buffers(shape: tuple) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """This thread's maps (x, y, z), product term and behind-the-camera mask for a ``shape`` frame."""
    bufs = getattr(_THREAD, "bufs", None)
    if bufs is None or bufs[1].shape != shape:
        bufs = ([np.empty(shape, np.float32) for _ in range(3)], np.empty(shape, np.float32), np.empty(shape, bool))
        _THREAD.bufs = bufs
    return bufs


class MonoCamera(SensorType):
    name = "camera"
    description = ("pinhole camera through the drive's renderer: exposure-time motion blur from the body's motion, "
                   "read noise, labels/depth/instances")
    Params = CameraParams
    message = "image"
    sensor_class = CameraSensor


class StereoPair(SensorType):
    name = "stereo"
    description = "rectified stereo pair (left mounted, right baseline_m along its x axis), motion blur like camera"
    Params = CameraParams
    message = "stereo"
    sensor_class = CameraSensor
    options = {"stereo": True}
