"""Batches of frames finished on the device: camera model and labels (``post_kernels``), one
copy to the host a batch. What ``WarpRenderer.render_finished`` runs; numpy + warp (+ cv2 for
the optics blur's Gaussian weights).

Why the batch's small inputs (ego lanes, blur weights, sensors, material looks) go up in one
copy each (:meth:`DeviceFinisher.upload`) and the results come back through pinned buffers
(:meth:`DeviceFinisher.launch_finish`, :meth:`DeviceFinisher.collect`): a copy from pageable
host memory waits for every kernel queued before it, so one small upload a frame made the host
wait for the GPU at every frame, and launching and rendering never overlapped."""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from . import post_kernels as pk

__all__ = ["DeviceFinisher", "gaussian_weights", "load_post_kernels", "make_sensor", "noise_seed32"]

LOG_K_RANGE = (math.log(1e-4), math.log(1e4))     # auto-exposure scales searched (as the CPU's bisection)
STAGED_TYPES = {"lane": wp.vec2, "blur_weights": float, "remap": wp.int32, "scale": wp.vec3}
RESULTS = ("rgb8", "labels", "depth", "inst", "lo", "hi")     # the buffers a batch brings back to the host


def load_post_kernels(device) -> None:
    """Compile or load the post kernels on ``device`` now."""
    wp.load_module(module=pk, device=device)


def noise_seed32(noise_seed) -> int:
    """The frame's noise seed (a tuple of ints: seed, frame, stream) as warp's 31-bit generator seed."""
    return int(np.random.SeedSequence([int(v) for v in noise_seed]).generate_state(1, np.uint32)[0]) & 0x7FFFFFFF


def make_sensor(effects, camera) -> pk.Sensor:
    """``ImageEffects`` (or None: plain tone mapping) of a frame seen by ``camera`` as a Sensor."""
    s = pk.Sensor()
    s.travel = wp.vec3(0.0, 0.0, 0.0)
    s.vignetting, s.target, s.exposure, s.gain, s.read_noise = 0.0, -1.0, 1.0, 0.0, 0.0
    s.wb, s.saturation, s.seed = wp.vec3(1.0, 1.0, 1.0), 1.0, 0
    if effects is None:
        return s
    if effects.travel_m > 0:                       # the car drives along the camera's horizontal heading
        f = camera.rotation[:, 2]
        h = np.array([f[0], f[1], 0.0])
        h /= max(float(np.linalg.norm(h)), 1e-12)
        s.travel = wp.vec3(*(camera.rotation.T @ (effects.travel_m * h)).astype(np.float32))
    s.vignetting = float(effects.vignetting)
    s.target = float(effects.target_luminance) if effects.target_luminance is not None else -1.0
    s.exposure, s.gain, s.read_noise = float(effects.exposure), float(effects.gain), float(effects.read_noise)
    s.wb, s.saturation = wp.vec3(*map(float, effects.wb_gains)), float(effects.saturation)
    s.seed = noise_seed32(effects.noise_seed)
    return s


def gaussian_weights(sigma: float) -> np.ndarray:
    """cv2.GaussianBlur's kernel for a float image and ``sigma`` (size round(8 sigma + 1), odd)."""
    import cv2

    size = int(round(sigma * 8 + 1)) | 1
    return cv2.getGaussianKernel(size, sigma, cv2.CV_32F).ravel()


class DeviceFinisher:
    """Device buffers for batches of ``batch`` frames of one size, and the kernels' launches."""

    def __init__(self, width: int, height: int, batch: int, device):
        self.width, self.height, self.batch, self.device = width, height, batch, wp.get_device(device)
        n = width * height
        load_post_kernels(self.device)
        z = lambda count, dtype: wp.zeros(count, dtype=dtype, device=self.device)  # noqa: E731
        self.lin, self.tmp = z(batch * n, wp.vec3), z(n, wp.vec3)
        self.rgb8, self.labels = z(batch * n * 3, wp.uint8), z(batch * n, wp.uint8)
        self.depth, self.inst = z(batch * n, float), z(batch * n, wp.int32)
        self.sums = z(batch * int(pk.AE_CANDIDATES) * int(pk.AE_CHUNKS), float)
        self.lo, self.hi = z(batch, float), z(batch, float)
        self.identity_lut = wp.array(np.arange(256, dtype=np.uint8), dtype=wp.uint8, device=self.device)
        self.no_lane = wp.zeros(2, dtype=wp.vec2, device=self.device)
        self._luts: dict = {}
        self._staged: list = []
        self._sensors = None
        self._host: dict | None = None
        self._queued = 0

    def frame(self, slot: int, cam, gb, sensor: pk.Sensor, blur_px: float, labels: dict) -> None:
        """Frame ``slot`` of the batch from its G-buffer ``gb`` (shaded): the image up to the
        exposure, the labels, depth and instances. ``labels``: label_distance, background, and
        optionally lane (local XY, (N, 2)), half_width, s_cam, plain / inside tables."""
        n, dev = self.width * self.height, self.device
        wp.launch(pk.motion_blur_kernel, dim=n, device=dev, inputs=[gb.rgb, gb.depth, cam, sensor.travel, slot],
                  outputs=[self.lin])
        if blur_px > 0:
            w = labels.get("blur_weights")      # staged by upload(), or made here
            if w is None:
                w = wp.array(gaussian_weights(blur_px), dtype=float, device=dev)
            view = self.lin[slot * n:(slot + 1) * n]
            r = (w.shape[0] - 1) // 2
            wp.launch(pk.gauss_kernel, dim=n, device=dev, inputs=[view, w, r, self.width, self.height, 1],
                      outputs=[self.tmp])
            wp.launch(pk.gauss_kernel, dim=n, device=dev, inputs=[self.tmp, w, r, self.width, self.height, 0],
                      outputs=[view])
        lane = labels.get("lane")
        lut = labels.get("plain") is not None
        if lane is None:
            lane_arr, n_lane = self.no_lane, 0
        elif isinstance(lane, wp.array):
            lane_arr, n_lane = lane, lane.shape[0]
        else:
            lane_arr, n_lane = wp.array(np.asarray(lane, np.float32), dtype=wp.vec2, device=dev), len(lane)
        plain, inside = self._tables(labels["plain"], labels["inside"]) if lut else (self.identity_lut,) * 2
        wp.launch(pk.labels_kernel, dim=n, device=dev,
                  inputs=[cam, gb.dist, gb.face, gb.cls, float(labels["label_distance"]), int(labels["background"]),
                          lane_arr, n_lane, float(labels.get("half_width", 0.0)), float(labels.get("s_cam", 0.0)),
                          plain, inside, int(lut), slot], outputs=[self.labels])
        wp.launch(pk.gather_kernel, dim=n, device=dev, inputs=[gb.depth, gb.inst, slot], outputs=[self.depth, self.inst])

    def _tables(self, plain: np.ndarray, inside: np.ndarray):
        """The class map's tables on the device (uploaded once: every frame of a render has the same)."""
        key = (np.asarray(plain, np.uint8).tobytes(), np.asarray(inside, np.uint8).tobytes())
        if key not in self._luts:
            self._luts[key] = tuple(wp.array(np.frombuffer(k, np.uint8), dtype=wp.uint8, device=self.device)
                                    for k in key)
        return self._luts[key]

    def upload(self, frames: list[dict]) -> list[dict]:
        """The batch's small inputs on the device, one copy a kind. ``frames``: per frame a dict
        with ``lane`` (local XY or None), ``blur_px``, ``sensor``, ``remap`` and ``scale`` (the
        material look). Returns per frame its device views: ``lane`` and ``blur_weights`` (None
        where it has none), ``remap``, ``scale``; the sensors wait for :meth:`launch_finish`."""
        host = {"lane": [None if f.get("lane") is None else np.asarray(f["lane"], np.float32).reshape(-1, 2)
                         for f in frames],
                "blur_weights": [gaussian_weights(f["blur_px"]) if f.get("blur_px", 0.0) > 0 else None
                                 for f in frames],
                "remap": [np.asarray(f["remap"], np.int32).reshape(-1) for f in frames],
                "scale": [np.asarray(f["scale"], np.float32).reshape(-1, 3) for f in frames]}
        views: list[dict] = [{} for _ in frames]
        self._staged = []                   # kept until the next upload (collect() has waited for them by then)
        for key, parts in host.items():
            present = [a for a in parts if a is not None]
            whole = wp.array(np.concatenate(present), dtype=STAGED_TYPES[key], device=self.device) if present else None
            self._staged.append(whole)
            at = 0
            for v, a in zip(views, parts):
                v[key] = None if a is None else whole[at:at + len(a)]
                at += 0 if a is None else len(a)
        self._sensors = wp.array([f["sensor"] for f in frames], dtype=pk.Sensor, device=self.device)
        return views

    def launch_finish(self, cam, sensors: list) -> None:
        """Queue auto-exposure, noise and tone mapping of the batch's ``len(sensors)`` frames and
        the copies back (``sensors`` uploaded by :meth:`upload` when it staged this batch)."""
        b, n, dev = len(sensors), self.width * self.height, self.device
        sens = self._sensors
        if sens is None or sens.shape[0] != b:
            sens = wp.array(sensors, dtype=pk.Sensor, device=dev)
        self._sensors = None
        self.lo.fill_(LOG_K_RANGE[0])
        self.hi.fill_(LOG_K_RANGE[1])
        if any(s.target > 0 for s in sensors):
            for _ in range(pk.AE_ROUNDS):
                wp.launch(pk.exposure_sums_kernel, dim=b * int(pk.AE_CANDIDATES) * int(pk.AE_CHUNKS), device=dev,
                          inputs=[self.lin, cam, sens, self.lo, self.hi], outputs=[self.sums])
                wp.launch(pk.exposure_bracket_kernel, dim=b, device=dev, inputs=[cam, sens, self.sums],
                          outputs=[self.lo, self.hi])
        wp.launch(pk.sensor_kernel, dim=b * n, device=dev, inputs=[self.lin, cam, sens, self.lo, self.hi],
                  outputs=[self.rgb8])
        self._queued = b
        if dev.is_cuda:                             # into pinned host memory: the copies run without the host
            if self._host is None:
                self._host = {k: wp.empty_like(getattr(self, k), device="cpu", pinned=True) for k in RESULTS}
            for k, host in self._host.items():
                wp.copy(host, getattr(self, k))

    def collect(self) -> dict:
        """The batch queued by :meth:`launch_finish`, once the device is done: rgb8 (B, H, W, 3)
        uint8, labels (B, H, W) uint8, depth, instance, exposure_scale (host copies)."""
        b, n, h, w = self._queued, self.width * self.height, self.height, self.width
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
            src = {k: v.numpy() for k, v in self._host.items()}
        else:
            src = {k: getattr(self, k).numpy() for k in RESULTS}
        return {"rgb8": src["rgb8"][:b * n * 3].reshape(b, h, w, 3).copy(),
                "labels": src["labels"][:b * n].reshape(b, h, w).copy(),
                "depth": src["depth"][:b * n].reshape(b, h, w).copy(),
                "instance": src["inst"][:b * n].reshape(b, h, w).copy(),
                "exposure_scale": np.exp(0.5 * (src["lo"][:b] + src["hi"][:b]))}

    def finish(self, cam, sensors: list) -> dict:
        """Auto-exposure, noise and tone mapping of the batch's ``len(sensors)`` frames; the
        host arrays (:meth:`collect`)."""
        self.launch_finish(cam, sensors)
        return self.collect()
