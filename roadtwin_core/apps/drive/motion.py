"""The vehicle's motion on the one simulation clock: the physics backend drives the vehicle
along the route, stretch by stretch of constant speed (the backend contract drives at a constant
speed; each stretch starts from the state the previous one ended in), and the result is a
:class:`Trajectory` sampled at the physics IMU rate (1 kHz by default) that every sensor reads.

Body frame ``base_link``: the sprung body's CG, x forward, y left, z up (roadtwin's vehicle
frame). Known limit: a speed change is a step between stretches, so the braking before a defect
is not in the IMU's longitudinal specific force.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ...errors import RoadtwinError
from ...vehicle import RoadMesh, SimParams, VehicleRun

__all__ = ["CORRIDOR_M", "Trajectory", "drive_vehicle", "crop_mesh", "euler_matrix", "write_trajectory"]

CORRIDOR_M = 8.0   # the road within this distance of the route is all the vehicle ever touches


def euler_matrix(roll, pitch, yaw) -> np.ndarray:
    """(..., 3, 3) body-to-world rotations, R = Rz(yaw) Ry(pitch) Rx(roll) (the backends' order)."""
    roll, pitch, yaw = (np.asarray(a, dtype=np.float64) for a in (roll, pitch, yaw))
    cf, sf, ct, st, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    R = np.stack([cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf,
                  sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf,
                  -st, ct * sf, ct * cf], axis=-1)
    return R.reshape(R.shape[:-1] + (3, 3))


@dataclass
class Trajectory:
    """The vehicle on the simulation clock. ``t`` (T,) seconds from the drive's start; ``pose``
    (T,6) CG x y z roll pitch yaw; ``acc`` (T,3) specific force at the CG, body frame (m/s^2,
    +9.81 z at rest); ``gyro`` (T,3) body rates (rad/s); ``wheel_z``/``tire_f``/``susp`` (T,4)
    FL FR RL RR; ``s`` (T,) arclength along the route; ``speed`` (T,) m/s."""

    t: np.ndarray
    pose: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    wheel_z: np.ndarray
    tire_f: np.ndarray
    susp: np.ndarray
    s: np.ndarray
    speed: np.ndarray
    meta: dict

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def _interp(self, arr: np.ndarray, t) -> np.ndarray:
        t = np.clip(np.asarray(t, dtype=np.float64), self.t[0], self.t[-1])
        return np.stack([np.interp(t, self.t, arr[:, k]) for k in range(arr.shape[1])], axis=-1)

    def _cached(self, name: str, make):
        """An array derived from the whole trajectory, made once (a sensor asks for poses
        tens of thousands of times a drive: remaking it each time made the drive quadratic)."""
        value = self.__dict__.get(name)
        if value is None:
            value = self.__dict__[name] = make()
        return value

    def pose_at(self, t) -> np.ndarray:
        """(..., 4, 4) body-to-world at times ``t`` (linear in x y z and in the angles)."""
        unwrapped = self._cached("_pose_unwrapped",
                                 lambda: np.column_stack([self.pose[:, :5], np.unwrap(self.pose[:, 5])]))
        p = self._interp(unwrapped, t)
        m = np.zeros(p.shape[:-1] + (4, 4))
        m[..., :3, :3] = euler_matrix(p[..., 3], p[..., 4], p[..., 5])
        m[..., :3, 3] = p[..., :3]
        m[..., 3, 3] = 1.0
        return m

    def velocity_at(self, t) -> np.ndarray:
        """(..., 3) world velocity of the CG."""
        return self._interp(self._cached("_velocity", lambda: np.gradient(self.pose[:, :3], self.t, axis=0)), t)

    def imu_truth(self, offset_body: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """Mean specific force (body frame) at the body point ``offset_body`` and mean body rate
        over ``[t0, t1)``: rigid-body transfer from the CG,
        f_p = f_cg + alpha x r + omega x (omega x r)."""
        i0 = int(np.searchsorted(self.t, t0 - 1e-9, side="right"))
        i1 = int(np.searchsorted(self.t, t1 + 1e-9, side="right"))
        i0 = min(i0, len(self.t) - 1)
        m = slice(i0, max(i1, i0 + 1))
        w = self.gyro[m]
        alpha = self._cached("_alpha", lambda: np.gradient(self.gyro, self.t, axis=0))[m]
        r = np.asarray(offset_body, dtype=np.float64)
        f = self.acc[m] + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
        return f.mean(0), w.mean(0)


def crop_mesh(road: RoadMesh, route_xy: np.ndarray, margin_m: float = CORRIDOR_M) -> RoadMesh:
    """The triangles within ``margin_m`` of the route (a smaller BVH; the wheels never leave it)."""
    seg = np.diff(route_xy, axis=0)
    L = np.linalg.norm(seg, axis=1)
    pts = [route_xy[:1]]
    for a, d, l in zip(route_xy[:-1], seg, L):
        n = max(1, int(math.ceil(l / 0.5)))
        pts.append(a + d * (np.arange(1, n + 1) / n)[:, None])
    tree = cKDTree(np.vstack(pts))
    cen = road.vertices[road.faces].mean(axis=1)[:, :2]
    ext = np.linalg.norm(road.vertices[road.faces][:, :, :2] - cen[:, None], axis=-1).max(1)
    d, _ = tree.query(cen)
    keep = d <= margin_m + ext
    used, inv = np.unique(road.faces[keep], return_inverse=True)
    return RoadMesh(road.vertices[used], inv.reshape(-1, 3), f"{road.name} (route corridor)")


def _extended(route_xy: np.ndarray, reach: float = 50.0) -> tuple[np.ndarray, float]:
    t0 = route_xy[1] - route_xy[0]
    t1 = route_xy[-1] - route_xy[-2]
    t0, t1 = t0 / np.linalg.norm(t0), t1 / np.linalg.norm(t1)
    return np.vstack([route_xy[0] - t0 * reach, route_xy, route_xy[-1] + t1 * reach]), reach


def drive_vehicle(backend, road: RoadMesh, vehicle, route, profile, sim: SimParams,
                  duration_s: float | None = None) -> Trajectory:
    """Drive ``vehicle`` along ``route`` with the ``profile`` on ``backend``; stretches of constant
    speed are simulated one after another, each starting in the state the last one ended in."""
    path, s_off = _extended(route.xy)
    pieces = profile.pieces(route.length)
    if duration_s is not None:   # cut the profile at the requested duration
        out, t_acc = [], 0.0
        for a, b, v in pieces:
            dt = (b - a) / v
            if t_acc + dt >= duration_s:
                out.append((a, a + (duration_s - t_acc) * v, v))
                break
            out.append((a, b, v))
            t_acc += dt
        pieces = out
    plain = vehicle.to_plain()
    chunks, state, t_base, wall = [], None, 0.0, 0.0
    imu_dt = None
    for a, b, v in pieces:
        dur = (b - a) / v
        run = VehicleRun(vehicle, path, s_off + a, v, dur, initial_state=state)
        tr = backend.simulate(road, [run], sim)
        wall += tr.meta["wall_s"]
        n = int(tr.valid[0])
        if n < 2:
            continue
        imu_dt = tr.meta.get("imu_dt", 1.0 / sim.imu_rate_hz)
        if tr.off_road[0] or not np.isfinite(tr.pose[0, :n]).all():
            bad = np.flatnonzero(~np.isfinite(tr.pose[0, :n, 2]))
            s_bad = a + v * (tr.t[bad[0]] if len(bad) else tr.t[n - 1])
            raise RoadtwinError(f"drive: a wheel lost the road at s = {s_bad:.1f} m along the route "
                                f"({route.source}); the route must stay on the collision mesh")
        t = tr.t[:n] + t_base
        chunks.append({"t": t, "pose": tr.pose[0, :n], "acc": tr.acc[0, :n], "gyro": tr.gyro[0, :n],
                       "wheel_z": tr.wheel_z[0, :n], "tire_f": tr.tire_f[0, :n], "susp": tr.susp[0, :n],
                       "s": a + v * tr.t[:n], "speed": np.full(n, v)})
        t_base = float(t[-1])
        # the state the next stretch starts in: z roll pitch and the suspensions, with their rates
        p, sp = tr.pose[0, :n], tr.susp[0, :n]
        s_static = np.array([c["s_static"] for c in plain["corners"]])
        state = {"q": p[-1, 2:5].tolist(), "qd": ((p[-1, 2:5] - p[-2, 2:5]) / imu_dt).tolist(),
                 "s": (sp[-1] + s_static).tolist(), "sd": ((sp[-1] - sp[-2]) / imu_dt).tolist()}
    if not chunks:
        raise RoadtwinError("drive: nothing to simulate (route or duration too short)")
    cat = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    meta = {"backend": backend.name, "stretches": len(chunks), "physics_wall_s": wall, "imu_dt": imu_dt,
            "dt": sim.dt_s, "triangles": int(len(road.faces))}
    return Trajectory(meta=meta, **cat)


def write_trajectory(path: Path, traj) -> None:
    step = max(1, int(round(0.01 / float(np.median(np.diff(traj.t))))))
    a = np.column_stack([traj.t, traj.pose, traj.s, traj.speed, traj.acc, traj.gyro])[::step]
    np.savetxt(path, a, delimiter=",", fmt="%.9g", comments="",
               header="t_s,x,y,z,roll,pitch,yaw,s_m,speed_mps,f_x,f_y,f_z,w_x,w_y,w_z")
