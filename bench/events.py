"""Event-camera benchmark: frames/s and events/s of the warp event simulator (the one the warp
renderer uses for CUDA frames) and of the numpy reference, at 640x480. Not a test.

    python3 bench/events.py --device cuda            # GPU: frames already on the device
    .venv/bin/python bench/events.py --device cpu --frames 20

It imports the roadtwin package (installed, or a checkout on ``PYTHONPATH=.:plugins``): the warp
event camera of the renderer plugin and the numpy reference of ``roadtwin_core.render.events``. Input: a periodic synthetic drive made on the
device (``--cycle`` frames of a textured scene under a drifting sinusoidal grating and a moving
bright bar, at ``--rate`` Hz), so the timed loop reads frames where a renderer would have left
them. Figures: ``device`` (events stay on the device: the GPU path's own speed), ``host`` (each
step's events copied back as numpy, what a dataset writer gets), the numpy reference on the same
frames (fewer of them), and a check that the first frames' events are the same on both.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda", help="warp device: cuda | cuda:N | cpu")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--frames", type=int, default=2000, help="timed frames of the warp simulator")
    ap.add_argument("--reference-frames", type=int, default=20, help="timed frames of the numpy reference")
    ap.add_argument("--cycle", type=int, default=200, help="distinct frames on the device (the drive repeats)")
    ap.add_argument("--rate", type=float, default=1000.0, help="frame rate of the drive (Hz)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.lower().split("x"))

    import roadtwin_core.render.events as EV
    import roadtwin_warp_render.event_kernels as EK
    from roadtwin_core.warp_runtime import start_warp

    wp = start_warp()
    dev = wp.get_device(args.device)

    @wp.kernel(enable_backward=False, module="unique")
    def drive_frame(tex: wp.array3d(dtype=wp.float32), phase: float, out: wp.array3d(dtype=wp.float32)):
        y, x = wp.tid()
        g = 1.0 + 0.3 * wp.sin(6.2831853 * (float(x) / 80.0 + float(y) / 240.0 - phase))
        bx = float(out.shape[1]) * phase
        d = wp.abs(float(x) - bx)
        bar = 1.0
        if d < 12.0:
            bar = 4.0
        for c in range(3):
            out[y, x, c] = tex[y, x, c] * g * bar

    rng = np.random.default_rng(0)
    tex = wp.array(rng.uniform(0.05, 1.0, (h, w, 3)).astype(np.float32), dtype=wp.float32, device=dev)
    t0 = time.perf_counter()
    frames = []
    for k in range(args.cycle):
        f = wp.empty((h, w, 3), dtype=wp.float32, device=dev)
        wp.launch(drive_frame, dim=(h, w), inputs=[tex, k / args.cycle, f], device=dev)
        frames.append(f)
    wp.synchronize_device(dev)
    t_make = time.perf_counter() - t0

    def times(n: int) -> np.ndarray:
        return np.arange(n) / args.rate

    # compile (the kernels' first launch), then a check on the first frames against numpy
    t0 = time.perf_counter()
    sim = EK.WarpEventSimulator(w, h, seed=0, device=args.device)
    sim.step_device(frames[0], 0.0)
    sim.step_device(frames[1], 1.0 / args.rate)
    wp.synchronize_device(dev)
    t_compile = time.perf_counter() - t0
    check_n = 4
    ref = EV.EventSimulator(w, h, seed=0)
    sim = EK.WarpEventSimulator(w, h, seed=0, device=args.device)
    same, n_check, dt_max = True, 0, 0.0
    for k, tt in enumerate(times(check_n)):
        a = ref.step(frames[k].numpy(), float(tt))
        b = sim.step(frames[k], float(tt))
        same &= all(len(a[key]) == len(b[key]) and np.array_equal(a[key], b[key]) for key in ("x", "y", "p"))
        if len(a["t"]) == len(b["t"]) and len(a["t"]):
            dt_max = max(dt_max, float(np.abs(a["t"] - b["t"]).max()))
        n_check += len(a["t"])

    def run_warp(n: int, host: bool) -> tuple[float, int]:
        s = EK.WarpEventSimulator(w, h, seed=0, device=args.device)
        ts = times(n + 1)
        s.step_device(frames[0], float(ts[0]))
        wp.synchronize_device(dev)
        count = 0
        t = time.perf_counter()
        for k in range(1, n + 1):
            f = frames[k % args.cycle]
            if host:
                count += len(s.step(f, float(ts[k]))["t"])
            else:
                count += s.step_device(f, float(ts[k]))[1]
        wp.synchronize_device(dev)
        return time.perf_counter() - t, count

    t_dev, n_dev = run_warp(args.frames, host=False)
    t_host, n_host = run_warp(args.frames, host=True)
    host_frames = [frames[k % args.cycle].numpy() for k in range(args.reference_frames + 1)]
    ref = EV.EventSimulator(w, h, seed=0)
    ts = times(args.reference_frames + 1)
    ref.step(host_frames[0], float(ts[0]))
    t = time.perf_counter()
    n_ref = sum(len(ref.step(host_frames[k], float(ts[k]))["t"]) for k in range(1, args.reference_frames + 1))
    t_ref = time.perf_counter() - t

    fig = {"size": f"{w}x{h}", "device": f"{dev} ({dev.name})" if dev.is_cuda else str(dev), "warp": wp.config.version,
           "kernel_cache": wp.config.kernel_cache_dir, "frames_made_s": round(t_make, 3),
           "compile_and_first_steps_s": round(t_compile, 2),
           "same_events_as_numpy_first_frames": bool(same), "checked_events": n_check, "max_abs_dt_s": dt_max,
           "device_frames": args.frames, "device_fps": args.frames / t_dev, "device_events_per_s": n_dev / t_dev,
           "events_per_frame": n_dev / args.frames,
           "host_fps": args.frames / t_host, "host_events_per_s": n_host / t_host,
           "numpy_frames": args.reference_frames, "numpy_fps": args.reference_frames / t_ref,
           "numpy_events_per_s": n_ref / t_ref}
    for k, v in fig.items():
        print(f"{k:>34}: {v:,.1f}" if isinstance(v, float) and v > 1 else f"{k:>34}: {v}")
    print("BENCH " + json.dumps({k: (round(v, 3) if isinstance(v, float) and v > 1e-3 else v) for k, v in fig.items()}))
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=2))


if __name__ == "__main__":
    main()
