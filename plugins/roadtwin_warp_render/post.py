"""Batches of frames finished on the device: camera model and labels (``post_kernels``), one
copy to the host a batch. What ``WarpRenderer.render_finished`` runs; numpy + warp (+ cv2 for
the optics blur's Gaussian weights)."""
from __future__ import annotations

import math

import numpy as np
import warp as wp

from . import post_kernels as pk

LOG_K_RANGE = (math.log(1e-4), math.log(1e4))     # auto-exposure scales searched (as the CPU's bisection)


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

    def frame(self, slot: int, cam, gb, sensor: pk.Sensor, blur_px: float, labels: dict) -> None:
        """Frame ``slot`` of the batch from its G-buffer ``gb`` (shaded): the image up to the
        exposure, the labels, depth and instances. ``labels``: label_distance, background, and
        optionally lane (local XY, (N, 2)), half_width, s_cam, plain / inside tables."""
        n, dev = self.width * self.height, self.device
        wp.launch(pk.motion_blur_kernel, dim=n, device=dev, inputs=[gb.rgb, gb.depth, cam, sensor.travel, slot],
                  outputs=[self.lin])
        if blur_px > 0:
            w = wp.array(gaussian_weights(blur_px), dtype=float, device=dev)
            view = self.lin[slot * n:(slot + 1) * n]
            r = (w.shape[0] - 1) // 2
            wp.launch(pk.gauss_kernel, dim=n, device=dev, inputs=[view, w, r, self.width, self.height, 1],
                      outputs=[self.tmp])
            wp.launch(pk.gauss_kernel, dim=n, device=dev, inputs=[self.tmp, w, r, self.width, self.height, 0],
                      outputs=[view])
        lane = labels.get("lane")
        lut = labels.get("plain") is not None
        lane_arr = self.no_lane if lane is None else wp.array(np.asarray(lane, np.float32), dtype=wp.vec2, device=dev)
        n_lane = 0 if lane is None else len(lane)
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

    def finish(self, cam, sensors: list) -> dict:
        """Auto-exposure, noise and tone mapping of the batch's ``len(sensors)`` frames; the
        host arrays: rgb8 (B, H, W, 3) uint8, labels (B, H, W) uint8, depth, instance."""
        b, n, dev = len(sensors), self.width * self.height, self.device
        sens = wp.array(sensors, dtype=pk.Sensor, device=dev)
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
        h, w = self.height, self.width
        return {"rgb8": self.rgb8.numpy()[:b * n * 3].reshape(b, h, w, 3).copy(),
                "labels": self.labels.numpy()[:b * n].reshape(b, h, w).copy(),
                "depth": self.depth.numpy()[:b * n].reshape(b, h, w).copy(),
                "instance": self.inst.numpy()[:b * n].reshape(b, h, w).copy(),
                "exposure_scale": np.exp(0.5 * (self.lo.numpy()[:b] + self.hi.numpy()[:b]))}
