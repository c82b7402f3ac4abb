"""``run_drive``: load the town, build the route and speed profile, drive the vehicle on the
physics backend, run every sensor of the rig on the one clock, write the outputs atomically.

The clock: the physics trajectory is sampled at ``1 / dt`` (1 kHz); sensor ``i`` samples at
``t = k / rate_i`` (k >= 1) up to the drive's end; all samples of all sensors are taken in time
order (ties in rig order) and streamed to the writers, so a long drive never holds its images.
"""
from __future__ import annotations

import importlib.util
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...atomic import atomic_output_dir
from ...errors import RoadtwinError
from ...params import apply_params
from ...plugins import get_plugin_manager
from ...render import RenderParams, build_render_mesh, stage_lanes
from ...render.lane_chains import chain_lanes
from ...usd.town_reader import load_town
from ...vehicle import RoadMesh, SimParams, VehicleParams, load_full_vehicle
from ...vehicle.roads import Occupancy
from .bag import BagWriter
from .contacts import contact_events, defect_footprints, write_events
from .motion import CORRIDOR_M, crop_mesh, drive_vehicle, write_trajectory
from .obstacles import check_clear, lane_obstacles
from .rig import load_rig, mount, override, select
from .route import build_route, check_on_road, constant_speed, read_recommendations, speed_profile, wheel_hits
from .rrd import RrdWriter
from .traffic import clear_of_ego, place_traffic
from .world import World

__all__ = ["DriveOptions", "run_drive", "SensorState"]


@dataclass
class DriveOptions:
    """What ``roadtwin drive`` takes (its options, same names): the route (``auto``, ``lane:ID,...``
    or a poses file) and how far or how long, the speed or a sweep's speed profile, the vehicle
    file and physics backend, the rig file, which of its sensors and parameters over its own
    (``sensor_params``), the renderer (and its
    ``--param`` values) for the cameras, which outputs; ``dt_s`` the physics step, ``truth_rate_hz``
    the rate of the ground-truth pose (``/tf``, ``/ground_truth/odom``, rerun); ``traffic`` other
    vehicles on the lanes at ``traffic_speed_kmh`` (kinematic: seen, not felt; :mod:`.traffic`),
    less those whose path would meet the ego's planned one (``traffic_left_out`` in the summary)."""

    route: str = "auto"
    length_m: float | None = 100.0
    duration_s: float | None = None
    speed_kmh: float = 30.0
    speed_profile: Path | None = None
    vehicle: Path | None = None
    backend: str = "warp"
    device: str = "cpu"
    renderer: str = "warp"
    rig: Path | None = None
    sensors: str | None = None
    sensor_params: dict = field(default_factory=dict)   # sensor id -> {parameter: value}, over the rig file's
    bag: bool = True
    rrd: bool = True
    compressed: bool = False
    dt_s: float = 1e-3
    truth_rate_hz: float = 100.0
    render_params: dict = field(default_factory=dict)
    traffic: int = 0
    traffic_speed_kmh: float = 30.0


class SensorState:
    """The vehicle at ``t`` on the drive's clock, as sensors see it."""

    def __init__(self, t: float, traj) -> None:
        self.t = float(t)
        self.trajectory = traj

    def pose_at(self, t):
        return self.trajectory.pose_at(t)

    def velocity_at(self, t):
        return self.trajectory.velocity_at(t)

    def imu_truth(self, offset_body, t0, t1):
        return self.trajectory.imu_truth(offset_body, t0, t1)


def _defect_table(town) -> list[dict]:
    """Each placed defect's centre and half its larger XY extent (from its mesh's bounds: cheap,
    so a bad route fails before any footprint polygon is made)."""
    out = []
    for d in town.defects:
        if "poseXYYaw" not in d.attributes:
            continue
        v, f = d.mesh()
        if len(f) == 0:
            continue
        xy = np.asarray(v)[np.unique(np.asarray(f))][:, :2]
        (x0, y0), (x1, y1) = xy.min(0), xy.max(0)
        out.append({"id": d.id, "type": d.defect_type, "xy": np.array(d.attributes["poseXYYaw"][:2], float),
                    "half_width_m": 0.5 * max(x1 - x0, y1 - y0)})
    return out


def _near_route(defects: list[dict], route, margin_m: float) -> set[str]:
    """Ids of the defects within ``margin_m`` (plus their own half width) of the route."""
    if not defects:
        return set()
    s, off = route.project(np.array([d["xy"] for d in defects]))
    keep = set()
    for d, si, oi in zip(defects, s, off):
        reach = margin_m + d["half_width_m"]
        if -reach <= si <= route.length + reach and abs(oi) <= reach:
            keep.add(d["id"])
    return keep


def check_options(opt: DriveOptions) -> None:
    if opt.length_m is not None and not (math.isfinite(opt.length_m) and 5.0 <= opt.length_m <= 100000.0):
        raise RoadtwinError(f"drive: --length must be in [5, 100000] m, got {opt.length_m}")
    if opt.duration_s is not None and not (math.isfinite(opt.duration_s) and 0.1 <= opt.duration_s <= 36000.0):
        raise RoadtwinError(f"drive: --duration must be in [0.1, 36000] s, got {opt.duration_s}")
    constant_speed(opt.speed_kmh)
    if isinstance(opt.traffic, bool) or not isinstance(opt.traffic, int) or not 0 <= opt.traffic <= 200:
        raise RoadtwinError(f"drive: --traffic must be an integer in [0, 200], got {opt.traffic!r}")
    if not (math.isfinite(opt.traffic_speed_kmh) and 0.0 <= opt.traffic_speed_kmh <= 200.0):
        raise RoadtwinError(f"drive: --traffic-speed must be in [0, 200] km/h, got {opt.traffic_speed_kmh}")
    if not (math.isfinite(opt.truth_rate_hz) and 0.0 < opt.truth_rate_hz <= 1000.0):
        raise RoadtwinError(f"drive: truth_rate_hz must be in (0, 1000] Hz, got {opt.truth_rate_hz}")
    for wanted, package, what, flag in ((opt.bag, "rosbags", "the ROS 2 bag", "--no-bag"),
                                        (opt.rrd, "rerun", "drive.rrd", "--no-rerun")):
        if wanted and importlib.util.find_spec(package) is None:
            raise RoadtwinError(f"drive: {what} needs {package} (pip install 'roadtwin[all]'), or give {flag}")


def load_stage(stage: Path, needs_render: bool) -> dict:
    """What every drive on ``stage`` shares (the town, its collision mesh, defects, lanes and
    render mesh): loaded once per process by ``run_drives``, whatever the number of routes."""
    town = load_town(stage, looks=needs_render)
    verts, faces = town.collision_mesh()
    return {"town": town, "road": RoadMesh(verts, faces, f"{stage.name} collision"), "defects": _defect_table(town),
            "lanes": stage_lanes(stage), "render_mesh": build_render_mesh(town)}


def prepare_drive(stage: Path, opt: DriveOptions, pm=None, loaded: dict | None = None) -> dict:
    """Everything that can fail on bad input, before any output is touched: the options, files
    and plugins first, then the town (the route on its road, the speed profile's defects).
    ``loaded``: a :func:`load_stage` result to reuse (its renderer scene is kept in it)."""
    check_options(opt)
    pm = pm or get_plugin_manager()
    stage = Path(stage)
    if not stage.is_file():
        raise RoadtwinError(f"{stage}: no such file")
    vehicle = load_full_vehicle(opt.vehicle, VehicleParams())
    rig_name, specs = load_rig(opt.rig)
    specs = override(select(specs, opt.sensors, rig_name), opt.sensor_params, rig_name)
    sensors = mount(pm, specs)
    recommended = (read_recommendations(opt.speed_profile, vehicle.name) if opt.speed_profile is not None
                   else None)
    backend = pm.get("physics_backends", opt.backend)
    needs_render = any(s.message in ("image", "stereo") for s in sensors)
    renderer = pm.get("renderers", opt.renderer) if needs_render else None
    rparams = apply_params(RenderParams(), opt.render_params, f"renderer {opt.renderer}") if opt.render_params \
        else RenderParams()
    sim = SimParams(dt_s=opt.dt_s, imu_rate_hz=1.0 / opt.dt_s, device=opt.device).check("drive")
    t0 = time.perf_counter()
    loaded = loaded if loaded is not None else load_stage(stage, needs_render)
    town, road, defects = loaded["town"], loaded["road"], loaded["defects"]
    half_track, half_tire = vehicle.track_front_m / 2, vehicle.tire_width_m / 2
    if "obstacles" not in loaded:
        loaded["obstacles"] = lane_obstacles(town)
    body = (vehicle.body_width_m, vehicle.body_length_m)
    route = build_route(opt.route, loaded["lanes"], defects, opt.length_m, half_track, half_tire,
                        loaded["obstacles"], body)
    if "occupancy" not in loaded:
        loaded["occupancy"] = Occupancy(road.vertices, road.faces)
    check_on_road(route, loaded["occupancy"], half_track, half_tire)
    check_clear(route, loaded["obstacles"], *body)
    hits = wheel_hits(route, defects, half_track, half_tire)
    profile = (speed_profile(recommended, hits, opt.speed_kmh, opt.speed_profile.name) if recommended is not None
               else constant_speed(opt.speed_kmh))
    # footprint polygons (contacts, the rerun map) only for the defects the drive can reach
    footprints = defect_footprints(town, _near_route(defects, route, CORRIDOR_M))
    world = loaded.get("world")
    if world is None or world.renderer is not renderer or world.source_params != rparams:
        world = loaded["world"] = World(loaded["render_mesh"], renderer, rparams)
    traffic, left_out = None, []
    if opt.traffic:     # along whole roads (a segment's lane is 25 m), none that would drive through the ego
        if "traffic_lanes" not in loaded:
            loaded["traffic_lanes"] = chain_lanes(loaded["lanes"])
        traffic, left_out = clear_of_ego(place_traffic(opt.traffic, loaded["traffic_lanes"], route,
                                                       opt.traffic_speed_kmh / 3.6, world.ground_z),
                                         route, profile, body, opt.duration_s)
    world.set_traffic(traffic)
    return {"town": town, "road": road, "footprints": footprints, "route": route, "profile": profile, "hits": hits,
            "vehicle": vehicle, "sensors": sensors, "backend": backend, "sim": sim, "rig": rig_name,
            "world": world, "traffic_left_out": len(left_out), "load_s": time.perf_counter() - t0}


def run_drive(stage: Path, out: Path, opt: DriveOptions, pm=None, progress=None, loaded: dict | None = None) -> dict:
    """Drive ``stage`` into the folder ``out`` (replaced whole, or left as it was on an error):
    ``bag/`` (ROS 2, MCAP), ``drive.rrd``, ``contacts.json``/``.csv``, ``trajectory.csv``, one
    ``<imu>.csv`` per IMU, ``frames.json`` (camera frames: time, sub-frames, pose) and
    ``summary.json`` (the same bytes for the same inputs) and ``timings.json`` (wall times).
    Returns the summary plus ``timings_s``, ``events`` and the ``trajectory``."""
    progress = progress or (lambda msg: None)
    ctx = prepare_drive(stage, opt, pm, loaded)
    t0 = time.perf_counter()
    ctx["world"].prepare(render=any(s.message in ("image", "stereo") for s in ctx["sensors"]),
                         cast=any(s.message == "points" for s in ctx["sensors"]))
    timings = {"load_s": ctx["load_s"] + time.perf_counter() - t0}
    t0 = time.perf_counter()
    road = crop_mesh(ctx["road"], ctx["route"].xy)
    traj = drive_vehicle(ctx["backend"], road, ctx["vehicle"], ctx["route"], ctx["profile"], ctx["sim"],
                         opt.duration_s)
    timings["physics_s"] = time.perf_counter() - t0
    events = contact_events(traj, ctx["vehicle"], ctx["footprints"],
                            {d.id: d.defect_type for d in ctx["town"].defects})
    progress(f"drove {traj.s[-1]:.1f} m in {traj.duration:.2f} s simulated; {len(events)} wheel-defect contacts")
    sensors, world = ctx["sensors"], ctx["world"]
    schedule = []
    for i, s in enumerate(sensors):
        n = int(math.floor(traj.duration * s.rate_hz + 1e-9))
        schedule += [(k / s.rate_hz, i) for k in range(1, n + 1)]
    truth_dt = 1.0 / opt.truth_rate_hz
    schedule += [(k * truth_dt, -1) for k in range(int(traj.duration / truth_dt) + 1)]
    schedule.sort(key=lambda e: (round(e[0], 9), e[1]))
    counts = {s.id: 0 for s in sensors}
    per_sensor_s = {s.id: 0.0 for s in sensors}
    with atomic_output_dir(out) as tmp:
        bag = None
        if opt.bag:
            bag = BagWriter(tmp / "bag", sensors, compressed=opt.compressed)
            bag.write_static(sensors)
        rrd = None
        if opt.rrd:
            rrd = RrdWriter(tmp / "drive.rrd")
            rrd.write_map(ctx["route"].xy, ctx["footprints"], float(np.nanmedian(traj.pose[:, 2])) - 0.5)
            rrd.write_events(events)
        samples_keep = {s.id: [] for s in sensors if s.message in ("imu",)}
        frames_meta = []
        t_loop = time.perf_counter()
        gyro_at = lambda t: np.array([np.interp(t, traj.t, traj.gyro[:, k]) for k in range(3)])
        for t, i in schedule:
            if i < 0:
                pose = traj.pose_at(t)
                if bag:
                    bag.write_truth(t, pose, traj.velocity_at(t), gyro_at(t))
                if rrd:
                    rrd.write_truth(t, pose)
                continue
            s = sensors[i]
            world.time = t
            ts = time.perf_counter()
            msg = s.sample(SensorState(t, traj), world)
            per_sensor_s[s.id] += time.perf_counter() - ts
            counts[s.id] += 1
            if s.id in samples_keep:
                samples_keep[s.id].append([msg["t"], *msg["linear_acceleration"], *msg["angular_velocity"]])
            if s.message in ("image", "stereo"):
                frames_meta.append({"sensor": s.id, "t": msg["t"], "subframes": msg["subframes"],
                                    "cam_to_world": msg["cam_to_world"].tolist()})
            if bag:
                bag.write(s, msg)
            if rrd:
                rrd.write(s, msg, traj.pose_at)
        timings["sensors_s"] = time.perf_counter() - t_loop
        if bag:
            bag.close()
        if rrd:
            rrd.close()
        write_events(tmp, events)
        write_trajectory(tmp / "trajectory.csv", traj)
        for sid, rows in samples_keep.items():
            np.savetxt(tmp / f"{sid}.csv", np.array(rows).reshape(-1, 7), delimiter=",", fmt="%.9g",
                       header="t_s,ax,ay,az,gx,gy,gz", comments="")
        (tmp / "frames.json").write_text(json.dumps(frames_meta))
        summary = {"stage": str(stage), "route": ctx["route"].source, "route_length_m": ctx["route"].length,
                   "driven_m": float(traj.s[-1]), "duration_s": traj.duration, "speed_profile": ctx["profile"].source,
                   "vehicle": ctx["vehicle"].name, "backend": opt.backend, "rig": ctx["rig"],
                   "sensors": {s.id: {"type": s.type, "rate_hz": s.rate_hz, "samples": counts[s.id]}
                               for s in sensors},
                   "traffic": [{"instance": i, "lane": v.lane.id, "s0_m": v.s0, "speed_kmh": v.speed_mps * 3.6}
                               for i, v in zip(getattr(world, "vehicle_instances", []),
                                               world.traffic.vehicles if world.traffic else [])],
                   "traffic_left_out": ctx["traffic_left_out"],
                   "contacts": len(events), "defects_in_wheel_tracks": [h["id"] for h in ctx["hits"]],
                   "instances": {str(k): v for k, v in world.instances.items()},
                   "classes": world.class_names,
                   "physics": {k: v for k, v in traj.meta.items() if k != "physics_wall_s"},
                   "bag_topics": dict(sorted(bag.counts.items())) if bag else {},
                   "files": {"bag": "bag/" if bag else None, "rerun": "drive.rrd" if rrd else None,
                              "contacts": ["contacts.json", "contacts.csv"], "trajectory": "trajectory.csv",
                              "timings": "timings.json"}}
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
        timings["physics_backend_s"] = traj.meta.get("physics_wall_s")
        timings["per_sensor_s"] = per_sensor_s
        (tmp / "timings.json").write_text(json.dumps(timings, indent=2, default=float))
    for sid, wall in per_sensor_s.items():
        summary["sensors"][sid]["wall_s"] = wall
    summary["timings_s"] = timings
    summary["events"] = events
    summary["trajectory"] = traj
    return summary
