"""Drive benchmark (issue 20): wall time of ``roadtwin drive`` on a composed town, split into
loading, physics and each sensor, for the issue's figure (a 1 km drive with a 1280x720 stereo pair
at 10 Hz, LiDAR at 10 Hz and IMU at 200 Hz) or a shorter one.

    .venv/bin/python bench/drive.py out/town/town.usda                       # 1 km, the issue's rig
    .venv/bin/python bench/drive.py out/town/town.usda --length 100 --size 320x180
    python bench/drive.py out/town/town.usda --device cuda                   # physics on CUDA; the
                                                  renderer follows --render-device (default: cpu)

Prints one JSON line: metres driven, simulated seconds, wall seconds per phase and per sensor,
samples per sensor, the realtime factor. ``--route auto`` chains the town's lanes; a town shorter
than ``--length`` along one chain drives what there is (the figure says how far it got). Not a test.
"""
from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

from roadtwin_core.apps.drive import DriveOptions, run_drive

RIG = """name = "bench"
[[sensor]]
name = "imu"
type = "imu"
rate_hz = 200
xyz = [0.3, 0.0, 1.05]
[[sensor]]
name = "lidar"
type = "lidar"
rate_hz = 10
xyz = [0.3, 0.0, 1.0]
ypr_deg = [0.0, -45.0, 0.0]
[[sensor]]
name = "stereo"
type = "stereo"
rate_hz = 10
xyz = [0.6, 0.06, 0.95]
ypr_deg = [0.0, -12.0, 0.0]
[sensor.params]
width = {w}
height = {h}
hfov_deg = 80.0
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stage", type=Path)
    ap.add_argument("--length", type=float, default=1000.0)
    ap.add_argument("--speed", type=float, default=30.0, help="km/h")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--device", default="cpu", help="physics device")
    ap.add_argument("--render-device", default=None, help="renderer device (cpu, cuda)")
    ap.add_argument("--no-bag", action="store_true")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        rig = Path(tmp) / "rig.toml"
        rig.write_text(RIG.format(w=w, h=h))
        opt = DriveOptions(route="auto", length_m=args.length, speed_kmh=args.speed, rig=rig, device=args.device,
                           bag=not args.no_bag, rrd=False,
                           render_params={"device": args.render_device} if args.render_device else {})
        t0 = time.perf_counter()
        res = run_drive(args.stage, Path(tmp) / "out", opt)
        wall = time.perf_counter() - t0
        bag_mb = sum(p.stat().st_size for p in (Path(tmp) / "out" / "bag").glob("*")) / 1e6 if not args.no_bag else 0
    print(json.dumps({"machine": platform.processor() or platform.machine(), "driven_m": round(res["driven_m"], 1),
                      "simulated_s": round(res["duration_s"], 2), "wall_s": round(wall, 2),
                      "realtime_factor": round(res["duration_s"] / wall, 3), "size": args.size,
                      "timings_s": {k: round(v, 2) for k, v in res["timings_s"].items()},
                      "sensors": {k: {"samples": v["samples"], "wall_s": round(v["wall_s"], 2)}
                                  for k, v in res["sensors"].items()}, "bag_mb": round(bag_mb, 1),
                      "route": res["route"]}))


if __name__ == "__main__":
    main()
