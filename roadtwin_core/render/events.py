"""An ESIM / v2e-style event camera simulated from consecutive rendered frames (numpy).

Model, per pixel:

- log intensity ``L = log(Y + eps)`` of the linear luminance ``Y``; between two frames ``L`` is
  taken to change linearly in time (ESIM's assumption);
- a memorised reference level ``ref`` (the level of the last event, initially the first
  frame's ``L``); whenever ``L`` crosses ``ref + C+`` (``ref - C-``) an ON (OFF) event fires and
  ``ref`` moves by one threshold, so one frame step can fire several events per pixel; each
  event's timestamp is where the linear ``L`` crosses that level (interpolated between frames);
- contrast thresholds ``C+``, ``C-`` drawn once per pixel from N(threshold, sigma) (seeded), at
  least ``min_threshold``;
- a refractory period: an event closer than ``refractory_s`` after the pixel's previous event is
  dropped (the reference still moves: the change it stood for is spent, as in ESIM's variant
  without a memory of suppressed events);
- polarity +1 (brighter) / -1 (darker); output sorted by time.

Not modelled: shot noise, leak events, pixel bandwidth (v2e's low-pass), hot pixels.
"""
from __future__ import annotations

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float64)


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB (H, W, 3) -> linear luminance (H, W)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    return rgb if rgb.ndim == 2 else rgb @ LUMA


class EventSimulator:
    def __init__(self, width: int, height: int, *, threshold: float = 0.2, sigma: float = 0.03,
                 refractory_s: float = 1e-4, eps: float = 1e-3, min_threshold: float = 0.01, seed: int = 0):
        if width <= 0 or height <= 0:
            raise ValueError(f"event camera size must be positive, got {width}x{height}")
        if not threshold > 0 or sigma < 0 or refractory_s < 0 or not eps > 0:
            raise ValueError("event camera: threshold and eps must be > 0, sigma and refractory >= 0")
        self.width, self.height = int(width), int(height)
        self.threshold, self.sigma, self.refractory_s, self.eps = threshold, sigma, refractory_s, eps
        rng = np.random.default_rng(seed)
        n = self.width * self.height
        self.c_pos = np.maximum(rng.normal(threshold, sigma, n), min_threshold)
        self.c_neg = np.maximum(rng.normal(threshold, sigma, n), min_threshold)
        self.ref: np.ndarray | None = None
        self.prev: np.ndarray | None = None
        self.t_prev = 0.0
        self.last_event = np.full(n, -np.inf)

    def params(self) -> dict:
        return {"model": "esim-linear-log", "threshold": self.threshold, "sigma": self.sigma,
                "refractory_s": self.refractory_s, "log_eps": self.eps}

    def _log(self, frame: np.ndarray) -> np.ndarray:
        y = luminance(frame)
        if y.shape != (self.height, self.width):
            raise ValueError(f"frame is {y.shape[1]}x{y.shape[0]}, event camera is {self.width}x{self.height}")
        return np.log(np.maximum(y, 0.0) + self.eps).ravel()

    def reset(self, frame: np.ndarray, t: float) -> None:
        self.prev = self._log(frame)
        self.ref = self.prev.copy()
        self.t_prev = float(t)
        self.last_event[:] = -np.inf

    def step(self, frame: np.ndarray, t: float) -> dict[str, np.ndarray]:
        """Events between the previous frame and this one at time ``t`` (s): x, y, t, p."""
        if self.prev is None:
            self.reset(frame, t)
            return _empty()
        t = float(t)
        dt = t - self.t_prev
        if dt <= 0:
            raise ValueError(f"frame times must increase (got {t} after {self.t_prev})")
        cur = self._log(frame)
        out = [self._cross(cur, dt, +1), self._cross(cur, dt, -1)]
        self.prev, self.t_prev = cur, t
        ev = {k: np.concatenate([o[k] for o in out]) for k in ("idx", "t", "p")}
        order = np.argsort(ev["t"], kind="stable")
        idx = ev["idx"][order]
        return {"x": (idx % self.width).astype(np.uint16), "y": (idx // self.width).astype(np.uint16),
                "t": ev["t"][order], "p": ev["p"][order].astype(np.int8)}

    def _cross(self, cur: np.ndarray, dt: float, sign: int) -> dict[str, np.ndarray]:
        c = self.c_pos if sign > 0 else self.c_neg
        change = sign * (cur - self.ref)
        n = np.floor(change / c + 1e-9).astype(np.int64)
        n = np.maximum(n, 0)
        pix = np.nonzero(n)[0]
        if not len(pix):
            return {"idx": np.zeros(0, np.int64), "t": np.zeros(0), "p": np.zeros(0, np.int8)}
        counts = n[pix]
        rep = np.repeat(pix, counts)
        first = np.repeat(np.cumsum(counts) - counts, counts)
        k = np.arange(len(rep)) - first + 1                     # 1..n per pixel
        level = self.ref[rep] + sign * k * c[rep]
        slope = cur[rep] - self.prev[rep]
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(slope != 0, (level - self.prev[rep]) / slope, 1.0)
        times = self.t_prev + np.clip(frac, 0.0, 1.0) * dt
        # refractory period, greedy per pixel: one step's crossings of a pixel are evenly spaced
        # (spacing C * dt / |dL|), so the kept ones are every m-th from the first allowed one.
        keep = np.ones(len(rep), dtype=bool)
        if self.refractory_s > 0:
            r = self.refractory_s
            with np.errstate(divide="ignore", invalid="ignore"):
                spacing = np.where(slope != 0, c[rep] * dt / np.abs(slope), np.inf)
            t1 = times - (k - 1) * np.where(np.isfinite(spacing), spacing, 0.0)
            wait = self.last_event[rep] + r - t1
            with np.errstate(divide="ignore", invalid="ignore"):
                j0 = np.where(wait <= 0, 0.0, np.ceil(np.minimum(wait / spacing - 1e-9, 2.0 ** 40)))
                m = np.maximum(np.ceil(np.minimum(r / spacing - 1e-9, 2.0 ** 40)), 1.0)
            j = (k - 1).astype(np.float64)
            keep = (j >= j0) & (np.mod(j - j0, m) == 0)
        self.ref[pix] += sign * counts * c[pix]
        kept_idx, kept_t = rep[keep], times[keep]
        if len(kept_idx):
            np.maximum.at(self.last_event, kept_idx, kept_t)
        return {"idx": kept_idx, "t": kept_t, "p": np.full(len(kept_idx), sign, np.int8)}


def _empty() -> dict[str, np.ndarray]:
    return {"x": np.zeros(0, np.uint16), "y": np.zeros(0, np.uint16), "t": np.zeros(0), "p": np.zeros(0, np.int8)}
