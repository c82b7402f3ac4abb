"""Drive benchmark (issue 20): wall time of ``roadtwin drive`` on a composed town, split into
loading, physics and each sensor, for the issue's figure (a 1 km drive with a 1280x720 stereo pair
at 10 Hz, LiDAR at 10 Hz and IMU at 200 Hz) or a shorter one, extrapolated to the kilometre.

    .venv/bin/python bench/drive.py out/town/town.usda                       # 1 km, the issue's rig
    .venv/bin/python bench/drive.py out/town/town.usda --length 20           # 20 m, extrapolated to 1 km
    python bench/drive.py out/town/town.usda --device cuda --render-device cuda     # on a GPU

Prints one JSON line: metres driven, simulated seconds, wall seconds per phase and per sensor,
samples per sensor, the realtime factor, the process's CPU seconds and the machine's load
(on a shared machine the wall time is the load's as much as the drive's), and ``per_simulated_s``
/ ``extrapolated_1km_s``: the physics and sensor walls scale with the simulated time (a 1 km drive
at 30 km/h is 120 s), loading (the town, the renderer's scene, the LiDAR's BVH:
``World.prepare``) does not. ``--route auto`` chains the town's lanes; a town shorter than
``--length`` along one chain drives what there is (the figure says how far it got: the sample
town's longest chain is 320 m). ``--blur render`` renders every motion-blur sub-frame (the cost before the
cameras reprojected one). Not a test.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from roadtwin_core.apps.drive import DriveOptions, run_drive

SENSORS = "imu,lidar,stereo"    # of the default rig (the paper's platform): the pair, LiDAR and IMU


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stage", type=Path)
    ap.add_argument("--length", type=float, default=1000.0)
    ap.add_argument("--speed", type=float, default=30.0, help="km/h")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--device", default="cpu", help="physics device")
    ap.add_argument("--render-device", default=None, help="renderer device (cpu, cuda)")
    ap.add_argument("--no-bag", action="store_true")
    ap.add_argument("--blur", default="reproject", help="the cameras' motion blur: reproject | render (every "
                                                        "sub-frame rendered: the cost before the reprojection)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        opt = DriveOptions(route="auto", length_m=args.length, speed_kmh=args.speed, sensors=SENSORS,
                           sensor_params={"stereo": {"width": w, "height": h, "blur": args.blur}}, device=args.device,
                           bag=not args.no_bag, rrd=False,
                           render_params={"device": args.render_device} if args.render_device else {})
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_drive(args.stage, Path(tmp) / "out", opt)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        bag_mb = sum(p.stat().st_size for p in (Path(tmp) / "out" / "bag").glob("*")) / 1e6 if not args.no_bag else 0
    t = res["timings_s"]
    per_s = {"physics": t["physics_s"] / res["duration_s"], "sensors": t["sensors_s"] / res["duration_s"]}
    km_s = 1000.0 / (args.speed / 3.6)
    print(json.dumps({"machine": platform.processor() or platform.machine(), "driven_m": round(res["driven_m"], 1),
                      "simulated_s": round(res["duration_s"], 2), "wall_s": round(wall, 2),
                      "process_cpu_s": round(cpu, 2), "load_average_1min": round(os.getloadavg()[0], 1),
                      "realtime_factor": round(res["duration_s"] / wall, 4), "size": args.size, "blur": args.blur,
                      "timings_s": {k: round(t[k], 2) for k in ("load_s", "physics_s", "sensors_s")},
                      "sensors": {k: {"samples": v["samples"], "wall_s": round(v["wall_s"], 2),
                                      "wall_per_sample_s": round(v["wall_s"] / max(v["samples"], 1), 4)}
                                  for k, v in res["sensors"].items()}, "bag_mb": round(bag_mb, 1),
                      "per_simulated_s": {k: round(v, 3) for k, v in per_s.items()},
                      "extrapolated_1km_s": round(t["load_s"] + km_s * sum(per_s.values()), 0),
                      "route": res["route"]}))


if __name__ == "__main__":
    main()
