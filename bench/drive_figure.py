"""The docs figure of one drive (issue 20): ``docs/drive/drive.png``, drawn from what
``roadtwin drive`` wrote (the ROS 2 bag, imu.csv, contacts.json, trajectory.csv), so it shows
the outputs a user loads, not the simulator's internals.

    .venv/bin/roadtwin compose stages/town.usda -o out/town
    .venv/bin/python bench/drive_figure.py out/town/town.usda            # ~1 min on two CPU cores

The drive: 2.6 s at 30 km/h along lane ``avenue1_02_1`` of the sample town, whose pothole lies in
the right wheel track 14 m in (the drive of tests/apps/test_drive.py, with larger images), with six
other vehicles on the lanes at 20 km/h (``--traffic``: boxes that the cameras and LiDAR see).
Panels: the forward camera before the pothole, the wheel camera at the front-right wheel's contact, the
map with the route, one LiDAR frame from above coloured by class, and the IMU's vertical
acceleration with the wheel-defect contacts marked.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from roadtwin_core.apps.drive import DriveOptions, run_drive  # noqa: E402
from roadtwin_core.apps.drive.rig import load_rig  # noqa: E402
from roadtwin_core.render import stage_lanes  # noqa: E402
from roadtwin_core.render.lane_chains import chain_lanes  # noqa: E402

LANE = "avenue1_02_1"
RIG = """name = "figure"
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
name = "front"
type = "camera"
rate_hz = 10
xyz = [0.6, 0.06, 0.95]
ypr_deg = [0.0, -12.0, 0.0]
[sensor.params]
width = 480
height = 270
hfov_deg = 80.0
[[sensor]]
name = "wheelcam"
type = "camera"
rate_hz = 20
xyz = [1.5, -1.0, 0.5]
ypr_deg = [150.0, -66.0, 0.0]
[sensor.params]
width = 320
height = 240
hfov_deg = 90.0
"""
WHEEL_COLOURS = {"FL": "tab:blue", "FR": "tab:red", "RL": "tab:cyan", "RR": "tab:orange"}
CLASS_COLOURS = {"driving": "#8a8a8a", "road": "#8a8a8a", "lane_marking": "#d8c800", "sidewalk": "#c8a878",
                 "pothole": "#e0201c", "crack": "#ff9a00", "patch": "#a040c0", "manhole": "#3070d0",
                 "terrain": "#9aa860", "vegetation": "#2f8a2f", "pole": "#202020", "sign": "#1060ff",
                 "vehicle": "#00c8ff"}
DEFECT_COLOURS = {"pothole": "#e0201c", "crack": "#ff9a00", "patch": "#a040c0", "manhole": "#3070d0"}


def bag_messages(folder: Path, topic: str) -> list:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(folder / "bag") as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [ts.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]


def stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - 1_700_000_000


def image(msg) -> np.ndarray:
    return np.frombuffer(msg.data.tobytes(), np.uint8).reshape(msg.height, msg.width, 3)


def lidar_world(msg, traj, extrinsic) -> tuple[np.ndarray, np.ndarray]:
    """The frame's points in the world (each with the sensor pose at its own time) and labels."""
    names = [f.name for f in msg.fields]
    offs = {f.name: f.offset for f in msg.fields}
    raw = np.frombuffer(msg.data.tobytes(), np.uint8).reshape(msg.width, msg.point_step)
    xyz = np.stack([raw[:, offs[a]:offs[a] + 4].copy().view(np.float32)[:, 0] for a in "xyz"], axis=1)
    t_ns = raw[:, offs["t"]:offs["t"] + 4].copy().view(np.uint32)[:, 0] if "t" in names else np.zeros(len(raw))
    label = raw[:, offs["label"]:offs["label"] + 2].copy().view(np.uint16)[:, 0]
    T = traj.pose_at(stamp(msg) + t_ns * 1e-9) @ extrinsic
    return np.einsum("nij,nj->ni", T[:, :3, :3], xyz.astype(np.float64)) + T[:, :3, 3], label


def draw(out_dir: Path, res: dict, stage: Path, png: Path, lidar_extrinsic: np.ndarray) -> None:
    traj, events = res["trajectory"], res["events"]
    fr = next(e for e in events if e["wheel"] == "FR" and e["defect_type"] == "pothole")
    t_hit = 0.5 * (fr["t_entry_s"] + fr["t_exit_s"])
    fig = plt.figure(figsize=(15, 8.6), layout="constrained")
    grid = fig.add_gridspec(2, 3, height_ratios=[1, 1])
    front = bag_messages(out_dir, "/front/image_raw")
    k = int(np.argmin([abs(stamp(m) - (fr["t_entry_s"] - 1.0)) for m in front]))
    ax = fig.add_subplot(grid[0, 0])
    ax.imshow(image(front[k]))
    ax.set_title(f"forward camera, t = {stamp(front[k]):.2f} s (pothole ahead)")
    ax.axis("off")
    wheel = bag_messages(out_dir, "/wheelcam/image_raw")
    k = int(np.argmin([abs(stamp(m) - t_hit) for m in wheel]))
    ax = fig.add_subplot(grid[0, 1])
    ax.imshow(image(wheel[k]))
    ax.set_title(f"wheel camera, t = {stamp(wheel[k]):.2f} s (FR wheel in {fr['defect']})")
    ax.axis("off")
    _map(fig.add_subplot(grid[0, 2]), stage, traj, events, res["traffic"], t_hit)
    _lidar(fig.add_subplot(grid[1, 0]), out_dir, res, traj, t_hit, lidar_extrinsic)
    _imu(fig.add_subplot(grid[1, 1:]), out_dir, events)
    fig.suptitle(f"roadtwin drive: {res['driven_m']:.1f} m in {res['duration_s']:.1f} s along {res['route']} "
                 f"({res['contacts']} wheel-defect contacts)")
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)


def _map(ax, stage: Path, traj, events, traffic: list, t: float) -> None:
    from roadtwin_core.usd.town_reader import load_town

    centre = traj.pose[len(traj.pose) // 2, :2]
    lanes = {lane.id: lane for lane in stage_lanes(stage)}
    for lane in lanes.values():
        ax.plot(lane.points[:, 0], lane.points[:, 1], color="0.7", lw=0.8)
    roads = {lane.id: lane for lane in chain_lanes(list(lanes.values()))}     # traffic drives whole roads
    for k, v in enumerate(traffic):
        lane = roads[v["lane"]]
        xy = lane.at([min(v["s0_m"] + v["speed_kmh"] / 3.6 * t, lane.length)])[0]
        ax.plot(*xy, "s", color="#00c8ff", ms=7, mec="k", label=f"other vehicles (t = {t:.2f} s)" if k == 0 else None)
    seen = set()
    for d in load_town(stage, looks=False).defects:
        if "poseXYYaw" in d.attributes:
            x, y = d.attributes["poseXYYaw"][:2]
            ax.plot(x, y, "o", ms=5, color=DEFECT_COLOURS.get(d.defect_type, "k"),
                    label=d.defect_type if d.defect_type not in seen else None)
            seen.add(d.defect_type)
    ax.plot(traj.pose[:, 0], traj.pose[:, 1], color="tab:blue", lw=3, label="route driven")
    for e in events:
        p = traj.pose_at(e["t_entry_s"])[:3, 3]
        ax.plot(p[0], p[1], "x", color=WHEEL_COLOURS[e["wheel"]], ms=10, mew=2)
    ax.set_xlim(centre[0] - 40, centre[0] + 40)
    ax.set_ylim(centre[1] - 40, centre[1] + 40)
    ax.set_aspect("equal")
    ax.set_title("map: lanes, defects, traffic, the route; x = contact")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="lower right", fontsize=7)


def _lidar(ax, out_dir: Path, res: dict, traj, t_hit: float, lidar_extrinsic: np.ndarray) -> None:
    frames = bag_messages(out_dir, "/lidar/points")
    k = int(np.argmin([abs(stamp(m) - (t_hit - 0.6)) for m in frames]))
    xyz, label = lidar_world(frames[k], traj, lidar_extrinsic)
    names = res["classes"]
    body = traj.pose_at(stamp(frames[k]))
    rel = (xyz - body[:3, 3]) @ body[:3, :3]          # bird's-eye in the body frame: x forward
    for c in np.unique(label):
        m = label == c
        name = names[c] if c < len(names) else str(c)
        ax.scatter(-rel[m, 1], rel[m, 0], s=1.5, color=CLASS_COLOURS.get(name, "#404040"), label=name,
                   zorder=3 if name in ("pothole", "crack", "vehicle") else 2)
    ax.set_aspect("equal")
    ax.set_xlim(-12, 12)
    ax.set_ylim(-2, 30)
    ax.set_title(f"LiDAR, t = {stamp(frames[k]):.2f} s, from above ({len(rel)} points)")
    ax.set_xlabel("right (m)")
    ax.set_ylabel("forward (m)")
    ax.legend(loc="upper left", markerscale=6, fontsize=7, ncol=2)


def _imu(ax, out_dir: Path, events: list) -> None:
    a = np.loadtxt(out_dir / "imu.csv", delimiter=",", skiprows=1)
    ax.plot(a[:, 0], a[:, 3], color="k", lw=0.9, label="IMU a_z (200 Hz, noise and bias)")
    for e in events:
        ax.axvspan(e["t_entry_s"], e["t_exit_s"], color=WHEEL_COLOURS[e["wheel"]], alpha=0.3)
        ax.text(e["t_entry_s"], ax.get_ylim()[1], f"{e['wheel']}\n{e['defect']}", fontsize=8, va="top",
                color=WHEEL_COLOURS[e["wheel"]])
    ax.set_xlabel("drive clock (s)")
    ax.set_ylabel("vertical specific force (m/s²)")
    ax.set_title("IMU vertical acceleration; shaded: a wheel on a defect (contacts.json)")
    ax.legend(loc="lower left")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stage", type=Path, help="the composed sample town (town.usda)")
    ap.add_argument("-o", "--out", type=Path, default=Path("docs/drive/drive.png"))
    ap.add_argument("--duration", type=float, default=2.6)
    ap.add_argument("--traffic", type=int, default=6, help="other vehicles on the lanes (kinematic boxes)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rig = Path(tmp) / "rig.toml"
        rig.write_text(RIG)
        out_dir = Path(tmp) / "drive"
        opt = DriveOptions(route=f"lane:{LANE}", length_m=None, duration_s=args.duration, speed_kmh=30.0, rig=rig,
                           rrd=False, traffic=args.traffic, traffic_speed_kmh=20.0)
        res = run_drive(args.stage, out_dir, opt)
        lidar_extrinsic = next(s.extrinsic for s in load_rig(rig)[1] if s.id == "lidar")
        draw(out_dir, res, args.stage, args.out, lidar_extrinsic)
        print(json.dumps({"figure": str(args.out), "contacts": res["contacts"], "driven_m": round(res["driven_m"], 1),
                          "timings_s": {k: round(v, 1) for k, v in res["timings_s"].items() if k.endswith("_s")
                                        and isinstance(v, float)}}))


if __name__ == "__main__":
    main()
