"""Physics benchmark: aggregate real-time factor (simulated vehicle-seconds per wall-second) of
the warp backend (CPU or CUDA) and the pybullet backend on the same runs.

    .venv/bin/python bench/sweep.py                         # warp-CPU vs pybullet, same runs, ratio
    .venv/bin/python bench/sweep.py --vehicles 16 --seconds 3
    python3 bench/sweep.py --device cuda --vehicles 4096 --mesh town01_like.npz

It imports the roadtwin package (installed, or a checkout on ``PYTHONPATH=.:plugins``): the
physics modules themselves, not copies, so it needs numpy, scipy, pluggy and warp (pybullet is
skipped when absent). ``--mesh FILE.npz``
(arrays ``vertices``, ``faces``) is loaded if it exists, else a synthetic Town01-sized road
network is generated with numpy and saved there: a 410 m x 340 m grid of 8 m wide two-lane roads
(6 east-west, 5 north-south) on a 0.2 m x 0.2 m height grid (about 1.6 M triangles) with an
ISO 8608 class-C-like roughness and 300 potholes (0.3-1.2 m, 2-8 cm deep). Without ``--mesh``
the CPU comparison uses a 240 m x 120 m piece of the same network (about 0.3 M triangles).

Vehicles: the default car, each on an east-west road lane (+-2 m from the road centre), at a
seeded random start and speed (20-60 km/h), for ``--seconds`` of simulated time at dt = 1 ms,
IMU at 500 Hz, 3 tire slices x (7 arc rays + 2 bisection rounds of 2) per wheel. Timing covers
the simulation loop only (kernel compilation, BVH / Bullet mesh building are reported
separately). Not a test.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- synthetic town
def town_mesh(width_m: float = 410.0, depth_m: float = 340.0, n_ew: int = 6, n_ns: int = 5, road_w: float = 8.0,
              dx: float = 0.2, potholes: int = 300, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Road strips as height grids; returns (vertices, faces, east-west road centre y's)."""
    rng = np.random.default_rng(seed)
    ys = np.linspace(20.0, depth_m - 20.0, n_ew)
    xs = np.linspace(20.0, width_m - 20.0, n_ns)
    # roughness: a sum of plane waves with an ISO 8608-like n^-2 displacement spectrum
    k = 64
    n = np.exp(rng.uniform(np.log(0.02), np.log(2.0), k))
    ang = rng.uniform(0, 2 * np.pi, k)
    amp = np.sqrt(2 * 256e-6 * (0.1 / n) ** 2 * n * np.log(100.0) / k)   # class C, log-spaced n
    ph = rng.uniform(0, 2 * np.pi, k)
    pot = np.column_stack([rng.uniform(0, width_m, potholes), np.zeros(potholes), rng.uniform(0.15, 0.6, potholes),
                           rng.uniform(0.02, 0.08, potholes)])
    pot[:, 1] = rng.choice(ys, potholes) + rng.uniform(-3.0, 3.0, potholes)

    def height(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        z = np.zeros_like(X)
        for i in range(k):
            z += amp[i] * np.cos(2 * np.pi * n[i] * (np.cos(ang[i]) * X + np.sin(ang[i]) * Y) + ph[i])
        gx, gy = X[0], Y[:, 0]
        for px, py, r, d in pot:  # potholes: flat floor, 10 % wall, on the grid cells they cover
            i0, i1 = np.searchsorted(gx, [px - r, px + r])
            j0, j1 = np.searchsorted(gy, [py - r, py + r])
            if i1 > i0 and j1 > j0:
                sub = np.s_[j0:j1, i0:i1]
                rho = np.hypot(X[sub] - px, Y[sub] - py) / r
                z[sub] -= d * np.clip((1 - rho) / 0.1, 0, 1)
        return z

    verts, faces, off = [], [], 0

    def strip(x0, x1, y0, y1):
        nonlocal off
        gx = np.linspace(x0, x1, int(round((x1 - x0) / dx)) + 1)
        gy = np.linspace(y0, y1, int(round((y1 - y0) / dx)) + 1)
        X, Y = np.meshgrid(gx, gy)
        v = np.column_stack([X.ravel(), Y.ravel(), height(X, Y).ravel()])
        nx = len(gx)
        i, j = np.meshgrid(np.arange(nx - 1), np.arange(len(gy) - 1))
        a = (j * nx + i).ravel()
        f = np.concatenate([np.column_stack([a, a + 1, a + nx + 1]), np.column_stack([a, a + nx + 1, a + nx])])
        verts.append(v)
        faces.append(f + off)
        off += len(v)

    for y in ys:
        strip(0.0, width_m, y - road_w / 2, y + road_w / 2)
    for x in xs:  # north-south roads between the east-west ones (no overlap)
        edges = np.concatenate([[0.0], ys, [depth_m]])
        for y0, y1 in zip(edges[:-1], edges[1:]):
            lo, hi = y0 + (road_w / 2 if y0 > 0 else 0), y1 - (road_w / 2 if y1 < depth_m else 0)
            if hi - lo > 2 * dx:
                strip(x - road_w / 2, x + road_w / 2, lo, hi)
    return np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int32), ys


def get_mesh(path: str | None, small: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    if path and Path(path).exists():
        d = np.load(path)
        return d["vertices"], d["faces"], d["road_y"], f"{path} (loaded)"
    t0 = time.perf_counter()
    if small:
        v, f, ys = town_mesh(240.0, 120.0, 3, 3, potholes=60)
    else:
        v, f, ys = town_mesh()
    note = f"synthetic, generated in {time.perf_counter() - t0:.1f} s"
    if path:
        np.savez(path, vertices=v, faces=f, road_y=ys)
        note += f", saved to {path}"
    return v, f, ys, note


def vehicles(n: int, road_y: np.ndarray, length: float, seconds: float, params: dict, seed: int = 7) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        y = road_y[i % len(road_y)] + (2.0 if (i // len(road_y)) % 2 else -2.0)
        v = rng.uniform(20, 60) / 3.6
        x0 = rng.uniform(5.0, max(6.0, length - 5.0 - v * seconds - 5.0))
        out.append({"params": params, "path": np.array([[0.0, y], [length, y]]), "s0": x0, "speed": v,
                    "duration": seconds})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu", help="warp device: cpu | cuda | cuda:N")
    ap.add_argument("--vehicles", type=int, default=None, help="vehicles (default: 8 on cpu, 4096 on cuda)")
    ap.add_argument("--seconds", type=float, default=None, help="simulated seconds per vehicle (default 2 / 5)")
    ap.add_argument("--mesh", default=None, help="road mesh .npz to load, or to write a synthetic Town01-sized one to")
    ap.add_argument("--no-pybullet", action="store_true", help="skip pybullet even when it is installed")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--bvh", default="sah", help="warp BVH constructor: sah (default) | median | lbvh | cubql")
    ap.add_argument("--slices", type=int, default=3, help="tire slices across the tread")
    ap.add_argument("--arcs", type=int, default=7, help="rays per slice over the lower arc")
    ap.add_argument("--refine", type=int, default=2, help="bisection rounds (2 rays each) around each slice's deepest ray")
    ap.add_argument("--dt", type=float, default=1e-3, help="time step (s)")
    ap.add_argument("--cache-dir", default=None, help="warp kernel cache folder (default: warp's, WARP_CACHE_PATH or "
                    "~/.cache/warp/VERSION); an empty one measures a first run's compile")
    ap.add_argument("--save", default=None, help="save the first 8 vehicles' IMU traces (.npz), to compare devices")
    args = ap.parse_args()
    cuda = args.device.startswith("cuda")
    n = args.vehicles or (4096 if cuda else 8)
    seconds = args.seconds or (5.0 if cuda else 2.0)

    import roadtwin_core.vehicle.vehicle as VP
    import roadtwin_warp_physics.kernels as K
    import warp as wp

    from roadtwin_core.warp_runtime import start_warp

    if args.cache_dir:
        wp.config.kernel_cache_dir = args.cache_dir
    start_warp()
    cache = Path(wp.config.kernel_cache_dir)
    cached = sorted(p.name for p in cache.iterdir()) if cache.is_dir() else []
    print(f"warp {wp.config.version}, kernel cache {cache}: {len(cached)} module(s) cached before this run")
    car = VP.VehicleParams().check().to_plain()
    v, f, road_y, note = get_mesh(args.mesh, small=not cuda and args.mesh is None)
    length = float(v[:, 0].max())
    runs = vehicles(n, road_y, length, seconds, car)
    print(f"mesh: {len(f):,} triangles, {len(v):,} vertices ({note})")
    print(f"runs: {n} vehicles x {seconds:g} s simulated, dt {args.dt * 1e3:g} ms, IMU 500 Hz, "
          f"{args.slices} slices x ({args.arcs} + 2 x {args.refine}) tire rays per wheel, BVH {args.bvh}")
    figures: dict = {"triangles": int(len(f)), "vehicles": n, "seconds": seconds, "host": platform.node(),
                     "python": platform.python_version(), "warp": wp.config.version}

    # warp: compile and build once on a short warm-up, then time the real run
    t0 = time.perf_counter()
    sim = K.VehicleSim(v, f, device=args.device, bvh_constructor=args.bvh)
    opts = {"dt": args.dt, "imu_rate_hz": 500.0, "tire_slices": args.slices, "tire_arc_samples": args.arcs,
            "tire_refine": args.refine}
    bvh = time.perf_counter() - t0
    t0 = time.perf_counter()
    first = (sim.run(runs[: min(n, 4)], **opts) if not cuda else
             sim.run([dict(r, duration=0.2) for r in runs], **opts))
    warm = time.perf_counter() - t0
    compile_s = first["compile_s"] if cuda else warm   # CPU: compile + the short warm-up run
    new = sorted(p.name for p in cache.iterdir() if p.name not in cached) if cache.is_dir() else []
    print(f"compile: {compile_s:.1f} s for the kernels of this run ({len(new)} module variant(s) compiled into the "
          f"cache: {', '.join(new) or 'none, all read from the cache'})")
    figures["compile_s"] = compile_s
    figures["compiled_modules"] = new
    res = sim.run(runs, **opts)
    rtf_w = res["sim_s"] / res["wall_s"]
    dead = int(np.sum(res["dead"]))
    label = f"warp-{'CUDA' if cuda else 'CPU'}"
    dev = str(sim.device) + (f" ({wp.get_device(args.device).name})" if cuda else "")
    print(f"{label}: {res['sim_s']:.1f} vehicle-s in {res['wall_s']:.3f} s -> real-time factor {rtf_w:,.1f}x "
          f"[device {dev}; BVH {bvh:.2f} s; compile + warm-up {warm:.1f} s; {dead} vehicle(s) left the road]")
    figures[label] = {"rtf": rtf_w, "wall_s": res["wall_s"], "sim_s": res["sim_s"], "bvh_s": bvh, "device": dev,
                      "off_road": dead}

    if args.save:
        np.savez_compressed(args.save, acc=res["acc"][:8].astype(np.float32), gyro=res["gyro"][:8].astype(np.float32),
                            t=res["t"])
    if not cuda and not args.no_pybullet:
        try:
            import roadtwin_pybullet.sim as S
        except ImportError as exc:
            print(f"pybullet: skipped ({exc})")
        else:
            t0 = time.perf_counter()
            world = S.BulletVehicleSim(v, f)
            build = time.perf_counter() - t0
            rb = world.run(runs, **opts)
            world.close()
            rtf_b = rb["sim_s"] / rb["wall_s"]
            print(f"pybullet: {rb['sim_s']:.1f} vehicle-s in {rb['wall_s']:.3f} s -> real-time factor {rtf_b:,.1f}x "
                  f"[{world.n_chunks} static mesh chunk(s), built in {build:.2f} s]")
            diff = float(np.nanmax(np.abs(rb["acc"][..., 2] - res["acc"][..., 2])))
            print(f"ratio warp-CPU / pybullet: {rtf_w / rtf_b:,.1f}x  (same runs; max |az| difference "
                  f"between the backends {diff:.3g} m/s^2)")
            figures["pybullet"] = {"rtf": rtf_b, "wall_s": rb["wall_s"], "sim_s": rb["sim_s"], "chunks": world.n_chunks}
            figures["ratio_warp_cpu_over_pybullet"] = rtf_w / rtf_b
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
