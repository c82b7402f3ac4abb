"""The event camera of ``roadtwin_core/render/events.py`` on warp: run it where the frames are.

Same model, same float64 arithmetic, same output order as the numpy reference
(:class:`roadtwin_core.render.events.EventSimulator`), so both give the same events; this one
keeps the per-pixel state (reference level, previous log frame, thresholds, last event time) on
the device and takes frames that are already there (a ``wp.array`` of shape (H, W, 3) or
(H, W), float32 or float64) or numpy frames (uploaded). One frame step is:

1. ``count``: one thread per pixel computes the log frame and how many ON and OFF events the
   pixel keeps (threshold crossings, refractory rule), state untouched;
2. an exclusive scan of the counts gives each pixel's slots: all ON events first, pixel by
   pixel, then all OFF events, which is the reference's order before its sort;
3. ``emit``: each thread writes its events there and moves its state (reference, last event);
4. a stable radix sort by time (the reference's ``argsort(kind="stable")``), then a gather.

Standalone (numpy + warp only), its own warp module so the renderer's ray
casting kernels are not compiled for it; no backward pass (nothing here is differentiated).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from roadtwin_core.warp_runtime import warp_device

wp.set_module_options({"enable_backward": False})

LUMA_R, LUMA_G, LUMA_B = 0.2126, 0.7152, 0.0722


@wp.func
def _log_luma(frame: wp.array3d(dtype=wp.float32), i: int, width: int, eps: wp.float64):
    """log(max(Y, 0) + eps) of pixel ``i``; a one-channel frame is Y itself."""
    y = i // width
    x = i % width
    lum = wp.float64(frame[y, x, 0])
    if frame.shape[2] == 3:
        lum = (wp.float64(frame[y, x, 0]) * wp.float64(LUMA_R) + wp.float64(frame[y, x, 1]) * wp.float64(LUMA_G)
               + wp.float64(frame[y, x, 2]) * wp.float64(LUMA_B))
    return wp.log(wp.max(lum, wp.float64(0.0)) + eps)


@wp.kernel
def log_kernel(frame: wp.array3d(dtype=wp.float32), width: int, eps: wp.float64, cur_out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    cur_out[i] = _log_luma(frame, i, width, eps)


@wp.func
def _cross(sign: int, cur: wp.float64, prev: wp.float64, ref: wp.float64, c: wp.float64, last: wp.float64,
           t_prev: wp.float64, dt: wp.float64, refr: wp.float64, out_t: wp.array(dtype=wp.float64), slot: int,
           write: int):
    """Kept crossings of one polarity at one pixel, written from ``slot`` when ``write``; returns
    (crossings, kept, latest kept time). The reference's arithmetic, operation by operation."""
    fs = wp.float64(sign)
    change = fs * (cur - ref)
    n = int(wp.floor(change / c + wp.float64(1e-9)))
    n = wp.max(n, 0)
    slope = cur - prev
    kept = int(0)
    latest = last
    inf = wp.float64(wp.inf)
    for k in range(1, n + 1):
        level = ref + wp.float64(sign * k) * c
        frac = wp.float64(1.0)
        spacing = inf
        if slope != wp.float64(0.0):
            frac = (level - prev) / slope
            spacing = c * dt / wp.abs(slope)
        t = t_prev + wp.clamp(frac, wp.float64(0.0), wp.float64(1.0)) * dt
        keep = True
        if refr > wp.float64(0.0):
            sp = wp.float64(0.0)
            if wp.isfinite(spacing):
                sp = spacing
            t1 = t - wp.float64(k - 1) * sp
            wait = last + refr - t1
            j0 = wp.float64(0.0)
            if not (wait <= wp.float64(0.0)):
                j0 = wp.ceil(wp.min(wait / spacing - wp.float64(1e-9), wp.float64(1099511627776.0)))
            m = wp.max(wp.ceil(wp.min(refr / spacing - wp.float64(1e-9), wp.float64(1099511627776.0))),
                       wp.float64(1.0))
            j = wp.float64(k - 1)
            keep = j >= j0 and wp.mod(j - j0, m) == wp.float64(0.0)
        if keep:
            if write != 0:
                out_t[slot + kept] = t
            kept += 1
            latest = wp.max(latest, t)
    return n, kept, latest


@wp.kernel
def count_kernel(frame: wp.array3d(dtype=wp.float32), width: int, eps: wp.float64, ref: wp.array(dtype=wp.float64),
                 prev: wp.array(dtype=wp.float64), c_pos: wp.array(dtype=wp.float64),
                 c_neg: wp.array(dtype=wp.float64), last: wp.array(dtype=wp.float64), t_prev: wp.float64,
                 dt: wp.float64, refr: wp.float64, cur_out: wp.array(dtype=wp.float64),
                 counts: wp.array(dtype=wp.int32), scratch: wp.array(dtype=wp.float64)):
    i = wp.tid()
    npx = ref.shape[0]
    cur = _log_luma(frame, i, width, eps)
    cur_out[i] = cur
    n_on, k_on, l_on = _cross(1, cur, prev[i], ref[i], c_pos[i], last[i], t_prev, dt, refr, scratch, 0, 0)
    ref_on = ref[i] + wp.float64(n_on) * c_pos[i]
    n_off, k_off, l_off = _cross(-1, cur, prev[i], ref_on, c_neg[i], l_on, t_prev, dt, refr, scratch, 0, 0)
    counts[i] = k_on
    counts[npx + i] = k_off


@wp.kernel
def emit_kernel(cur_in: wp.array(dtype=wp.float64), ref: wp.array(dtype=wp.float64), prev: wp.array(dtype=wp.float64),
                c_pos: wp.array(dtype=wp.float64), c_neg: wp.array(dtype=wp.float64),
                last: wp.array(dtype=wp.float64), t_prev: wp.float64, dt: wp.float64, refr: wp.float64,
                offsets: wp.array(dtype=wp.int32), ev_t: wp.array(dtype=wp.float64), ev_key: wp.array(dtype=wp.float64),
                ev_slot: wp.array(dtype=wp.int32)):
    i = wp.tid()
    npx = ref.shape[0]
    cur = cur_in[i]
    o_on = offsets[i]
    n_on, k_on, l_on = _cross(1, cur, prev[i], ref[i], c_pos[i], last[i], t_prev, dt, refr, ev_t, o_on, 1)
    r = ref[i] + wp.float64(n_on) * c_pos[i]
    o_off = offsets[npx + i]
    n_off, k_off, l_off = _cross(-1, cur, prev[i], r, c_neg[i], l_on, t_prev, dt, refr, ev_t, o_off, 1)
    ref[i] = r - wp.float64(n_off) * c_neg[i]
    prev[i] = cur
    last[i] = l_off
    for s in range(o_on, o_on + k_on):
        ev_key[s] = ev_t[s]
        ev_slot[s] = s
    for s in range(o_off, o_off + k_off):
        ev_key[s] = ev_t[s]
        ev_slot[s] = s


@wp.kernel
def owner_kernel(offsets: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
                 owner: wp.array(dtype=wp.int32)):
    """Slot -> (pixel, polarity) code: pixel for ON, -1 - pixel for OFF."""
    i = wp.tid()
    npx = (counts.shape[0] - 1) // 2
    code = i
    if i >= npx:
        code = -1 - (i - npx)
    for s in range(offsets[i], offsets[i] + counts[i]):
        owner[s] = code


@wp.kernel
def gather_kernel(order: wp.array(dtype=wp.int32), ev_t: wp.array(dtype=wp.float64), owner: wp.array(dtype=wp.int32),
                  width: int, x: wp.array(dtype=wp.uint16), y: wp.array(dtype=wp.uint16),
                  t: wp.array(dtype=wp.float64), p: wp.array(dtype=wp.int8)):
    e = wp.tid()
    s = order[e]
    code = owner[s]
    pol = 1
    if code < 0:
        code = -1 - code
        pol = -1
    x[e] = wp.uint16(code % width)
    y[e] = wp.uint16(code // width)
    t[e] = ev_t[s]
    p[e] = wp.int8(pol)


class WarpEventSimulator:
    """Drop-in for the numpy ``EventSimulator`` (same constructor, ``params``, ``reset``,
    ``step``) whose state and arithmetic live on a warp device; ``step_device`` leaves the
    events there (``(x, y, t, p)`` arrays of length ``count``)."""

    def __init__(self, width: int, height: int, *, threshold: float = 0.2, sigma: float = 0.03,
                 refractory_s: float = 1e-4, eps: float = 1e-3, min_threshold: float = 0.01, seed: int = 0,
                 device: str = "cuda"):
        if width <= 0 or height <= 0:
            raise ValueError(f"event camera size must be positive, got {width}x{height}")
        if not threshold > 0 or sigma < 0 or refractory_s < 0 or not eps > 0:
            raise ValueError("event camera: threshold and eps must be > 0, sigma and refractory >= 0")
        self.device = warp_device(device)
        self.width, self.height = int(width), int(height)
        self.threshold, self.sigma, self.refractory_s, self.eps = threshold, sigma, refractory_s, eps
        rng = np.random.default_rng(seed)    # the reference's draws, in its order
        n = self.width * self.height
        dev = self.device
        self.c_pos = wp.array(np.maximum(rng.normal(threshold, sigma, n), min_threshold), dtype=wp.float64, device=dev)
        self.c_neg = wp.array(np.maximum(rng.normal(threshold, sigma, n), min_threshold), dtype=wp.float64, device=dev)
        self.ref = wp.zeros(n, dtype=wp.float64, device=dev)
        self.prev = wp.zeros(n, dtype=wp.float64, device=dev)
        self.cur = wp.zeros(n, dtype=wp.float64, device=dev)
        self.last = wp.full(n, -np.inf, dtype=wp.float64, device=dev)
        self.counts = wp.zeros(2 * n + 1, dtype=wp.int32, device=dev)    # ON, OFF per pixel, then a 0
        self.offsets = wp.zeros(2 * n + 1, dtype=wp.int32, device=dev)   # exclusive scan: the last is the total
        self.started = False
        self.t_prev = 0.0
        self.capacity = 0
        self._grow(max(1024, n // 4))

    def params(self) -> dict:
        return {"model": "esim-linear-log", "threshold": self.threshold, "sigma": self.sigma,
                "refractory_s": self.refractory_s, "log_eps": self.eps}

    def _grow(self, need: int) -> None:
        if need <= self.capacity:
            return
        cap = max(need, 2 * self.capacity)
        dev = self.device
        self.ev_t = wp.empty(cap, dtype=wp.float64, device=dev)
        self.owner = wp.empty(cap, dtype=wp.int32, device=dev)
        self.keys = wp.empty(2 * cap, dtype=wp.float64, device=dev)   # radix sort needs 2x room
        self.order = wp.empty(2 * cap, dtype=wp.int32, device=dev)
        self.out = {"x": wp.empty(cap, dtype=wp.uint16, device=dev), "y": wp.empty(cap, dtype=wp.uint16, device=dev),
                    "t": wp.empty(cap, dtype=wp.float64, device=dev), "p": wp.empty(cap, dtype=wp.int8, device=dev)}
        self.capacity = cap

    def _frame(self, frame) -> wp.array:
        if isinstance(frame, wp.array) and frame.dtype == wp.vec3 and frame.ndim == 1 and frame.device == self.device \
                and frame.shape[0] == self.width * self.height and frame.is_contiguous:
            # the renderer's RGB buffer (one vec3 per pixel, row-major): read in place, no copy
            self._held = frame
            return wp.array(ptr=frame.ptr, dtype=wp.float32, shape=(self.height, self.width, 3), device=self.device)
        if isinstance(frame, wp.array):
            shape = frame.shape
            arr = frame
            if frame.dtype != wp.float32 or frame.device != self.device:
                arr = wp.array(frame.numpy().astype(np.float32), dtype=wp.float32, device=self.device)
        else:
            a = np.asarray(frame)
            shape = a.shape
            arr = None
        if len(shape) not in (2, 3) or tuple(shape[:2]) != (self.height, self.width) or (
                len(shape) == 3 and shape[2] != 3):
            raise ValueError(f"frame is {shape[1] if len(shape) > 1 else '?'}x{shape[0]}, event camera is "
                             f"{self.width}x{self.height}")
        if arr is None:
            a = np.asarray(frame, dtype=np.float32)
            arr = wp.array(a, dtype=wp.float32, device=self.device)
        if len(shape) == 2:   # luminance given
            arr = arr.reshape((self.height, self.width, 1))
        return arr

    def reset(self, frame, t: float) -> None:
        arr = self._frame(frame)
        n = self.width * self.height
        wp.launch(log_kernel, dim=n, inputs=[arr, self.width, float(self.eps), self.cur], device=self.device)
        wp.copy(self.prev, self.cur)
        wp.copy(self.ref, self.cur)
        self.last.fill_(-np.inf)
        self.t_prev = float(t)
        self.started = True

    def step_device(self, frame, t: float):
        """Events since the previous frame, left on the device: ``({x, y, t, p} arrays, count)``."""
        if not self.started:
            self.reset(frame, t)
            return {k: v[:0] for k, v in self.out.items()}, 0
        t = float(t)
        dt = t - self.t_prev
        if dt <= 0:
            raise ValueError(f"frame times must increase (got {t} after {self.t_prev})")
        arr = self._frame(frame)
        n = self.width * self.height
        dev = self.device
        refr = float(self.refractory_s)
        wp.launch(count_kernel, dim=n, inputs=[arr, self.width, float(self.eps), self.ref, self.prev, self.c_pos,
                                               self.c_neg, self.last, self.t_prev, dt, refr, self.cur, self.counts,
                                               self.ev_t], device=dev)
        wp.utils.array_scan(self.counts, self.offsets, inclusive=False)
        total = int(self.offsets[2 * n:].numpy()[0])   # the one host sync of a step
        self._grow(total)
        wp.launch(emit_kernel, dim=n, inputs=[self.cur, self.ref, self.prev, self.c_pos, self.c_neg, self.last,
                                              self.t_prev, dt, refr, self.offsets, self.ev_t, self.keys, self.order],
                  device=dev)
        self.t_prev = t
        if total == 0:
            return {k: v[:0] for k, v in self.out.items()}, 0
        wp.launch(owner_kernel, dim=2 * n, inputs=[self.offsets, self.counts, self.owner], device=dev)
        wp.utils.radix_sort_pairs(self.keys, self.order, total)
        o = self.out
        wp.launch(gather_kernel, dim=total, inputs=[self.order, self.ev_t, self.owner, self.width, o["x"], o["y"],
                                                    o["t"], o["p"]], device=dev)
        return {k: v[:total] for k, v in o.items()}, total

    def step(self, frame, t: float) -> dict[str, np.ndarray]:
        """Events between the previous frame and this one at time ``t`` (s): numpy x, y, t, p."""
        ev, _count = self.step_device(frame, t)
        if self.device.is_cpu:   # CPU arrays' numpy() are views of buffers the next step reuses
            return {k: v.numpy().copy() for k, v in ev.items()}
        return {k: v.numpy() for k, v in ev.items()}
