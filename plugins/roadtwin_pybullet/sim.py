"""The roadtwin vehicle as a Bullet multibody over a static concave triangle mesh.

numpy + pybullet + roadtwin's path resampling (the one every backend drives along). The roadtwin
plugin (``__init__.py``) adapts roadtwin's types to :class:`BulletVehicleSim`.

The vehicle is the same mechanical system as the warp backend's (see its ``kernels.py``), built
the Bullet way and integrated by Bullet's Featherstone solver:

* a fixed base, then a joint chain prismatic X -> prismatic Y -> revolute Z (yaw) -> prismatic Z
  (heave) -> revolute Y (pitch) -> revolute X (roll) = the body link (sprung mass, principal
  inertias at the CG), so the body pose is R = Rz(yaw) Ry(pitch) Rx(roll). X, Y and yaw are
  prescribed by the path (constant speed): their joint states are reset every step and
  velocity motors with a huge force limit hold them during the step. Heave, pitch and roll are
  free (motors off, no joint/link damping).
* four prismatic suspension joints along the body z axis to the wheel links (unsprung mass),
  driven by the spring-damper-stop force through TORQUE_CONTROL (the motors' default velocity
  servo switched off with force 0).
* road: the mesh as static ``GEOM_MESH`` bodies with ``GEOM_FORCE_CONCAVE_TRIMESH`` (Bullet's
  BVH triangle mesh), split into chunks grouped along the road's long axis, each within
  pybullet's limits for one mesh shape (174,762 triangles = 524,288 indices, 131,072 vertices).
* tires: the links carry no collision shapes; each step the contact patch is found with
  ``rayTestBatch`` against the road bodies (the same lateral slices, lower-arc rays and bisection
  rounds around each slice's deepest ray as the warp backend) and each slice's radial spring-damper force is applied to the wheel link at the
  slice centre with ``applyExternalForce``. Bullet's own rigid contact is not used for the
  tires: a cylinder-vs-trimesh manifold has a varying number of points, each a separate
  penalty/ERP spring, so there would be no well-defined tire stiffness and the two backends
  would model different tires.
* IMU: after each step the body link's world velocity and angular velocity are read back, the
  IMU point's velocity is finite-differenced and rotated into the body frame (minus gravity);
  samples are means over each IMU interval, exactly as in the warp backend.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pybullet as pb

from roadtwin_core.vehicle import resample_path, resampled_path_at

GRAVITY = 9.81
MAX_RAYS = getattr(pb, "MAX_RAY_INTERSECTION_BATCH_SIZE", 16384)
EPS_MASS = 1e-4          # the massless joints of the chain (x, y, yaw, heave, pitch frames)
EPS_INERTIA = 1e-6
KINEMATIC_FORCE = 1e9
# pybullet's createCollisionShape(GEOM_MESH) takes at most 131072 vertices and 524288 indices
MAX_MESH_VERTICES = 131072
MAX_MESH_TRIANGLES = 524288 // 3


# joint/link indices of the full vehicle's chain (see the module docs)
PATH_JOINTS = [0, 1, 2]                     # prismatic x, prismatic y, revolute yaw: prescribed
SUSPENSION_JOINTS = [6, 7, 8, 9]            # wheel links FL, FR, RL, RR
BODY_AND_WHEEL_LINKS = [5, 6, 7, 8, 9]      # the body link, then the wheels
POSE_FROM_JOINTS = [0, 1, 3, 5, 4, 2]       # x, y, heave, roll, pitch, yaw from the joint positions
GZ = np.array([0.0, 0.0, GRAVITY])


@dataclass
class _Clock:
    """Steps and IMU samples of a batch."""
    dt: float
    imu_every: int          # steps per IMU sample
    nsteps: np.ndarray      # (n,) steps of each vehicle, whole IMU intervals
    samples: int            # IMU samples of the longest vehicle
    lost_limit: int         # steps a wheel may be off the road

    @classmethod
    def of(cls, vehicles: list[dict], dt: float, imu_rate_hz: float, lost_after_s: float) -> "_Clock":
        imu_every = max(1, int(round(1.0 / (imu_rate_hz * dt))))
        nsteps = np.array([int(round(v["duration"] / dt)) for v in vehicles])
        nsteps = (nsteps // imu_every) * imu_every
        return cls(dt, imu_every, nsteps, int(nsteps.max() // imu_every), int(round(lost_after_s / dt)))


@dataclass
class _TireRays:
    """The contact sampling: ``nl`` slices, ``na`` arc rays over +-``arc`` rad, ``refine`` rounds."""
    nl: int
    na: int
    arc: float
    refine: int
    step_a: float
    alpha: np.ndarray       # (na,) ray angles
    dirs_b: np.ndarray      # (na, 3) ray directions, body frame

    @classmethod
    def of(cls, slices: int, arc_samples: int, arc_deg: float, refine: int) -> "_TireRays":
        arc = math.radians(arc_deg)
        step_a = 2.0 * arc / (arc_samples - 1) if arc_samples > 1 else 0.0
        alpha = -arc + step_a * np.arange(arc_samples)
        dirs_b = np.stack([np.sin(alpha), np.zeros(arc_samples), -np.cos(alpha)], -1)
        return cls(slices, arc_samples, arc, int(refine), step_a, alpha, dirs_b)


@dataclass
class _FullFleet:
    """Per-vehicle constants of a batch of full vehicles as arrays ((n,) or (n, 4) per corner)."""
    radius: np.ndarray
    yoff: np.ndarray        # (n, nl) lateral offsets of the tire slices
    kt: np.ndarray
    ct: np.ndarray
    ks: np.ndarray
    cs: np.ndarray
    smin: np.ndarray
    smax: np.ndarray
    sstat: np.ndarray
    kstop: np.ndarray       # (n, 1)
    cstop: np.ndarray       # (n, 1)
    r_imu: np.ndarray       # (n, 3)

    @classmethod
    def of(cls, params: list[dict], nl: int) -> "_FullFleet":
        def corner(key):
            return np.array([[k[key] for k in p["corners"]] for p in params])

        def body(key):
            return np.array([p[key] for p in params])

        width = body("width")
        return cls(radius=body("radius"), yoff=((np.arange(nl) + 0.5) / nl - 0.5)[None, :] * width[:, None],
                   kt=body("kt"), ct=body("ct"), ks=corner("ks"), cs=corner("cs"), smin=corner("s_min"),
                   smax=corner("s_max"), sstat=corner("s_static"), kstop=body("k_stop")[:, None],
                   cstop=body("c_stop")[:, None], r_imu=body("imu"))

    def suspension_forces(self, act: np.ndarray, sj: np.ndarray, sdj: np.ndarray) -> np.ndarray:
        """(A, 4) joint forces: spring + damper + the stops past the travel limits (never pulling)."""
        smin, smax, kstop, cstop = self.smin[act], self.smax[act], self.kstop[act], self.cstop[act]
        stop = np.where(sj > smax, np.maximum(kstop * (sj - smax) + cstop * sdj, 0.0),
                        np.where(sj < smin, np.minimum(kstop * (sj - smin) + cstop * sdj, 0.0), 0.0))
        return -(self.ks[act] * sj + self.cs[act] * sdj + stop)


@dataclass
class _FullState:
    """What the stepping loop carries from step to step."""
    dead: np.ndarray
    lost: np.ndarray
    steps: np.ndarray
    vimu_prev: np.ndarray
    acc_sum: np.ndarray
    gyro_sum: np.ndarray
    last_tire: dict = field(default_factory=dict)

    @classmethod
    def zeros(cls, n: int) -> "_FullState":
        return cls(np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64),
                   np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)))


@dataclass
class _Readback:
    """States read back from Bullet for A vehicles."""
    Rb: np.ndarray          # (A, 3, 3) body rotation
    vb: np.ndarray          # (A, 3) body CG velocity (world)
    omg: np.ndarray         # (A, 3) body angular velocity (world)
    wpos: np.ndarray        # (A, 4, 3) wheel centres
    wvel: np.ndarray        # (A, 4, 3) wheel velocities
    q: np.ndarray           # (A, 10) joint positions
    qdot: np.ndarray        # (A, 10) joint velocities

    def subset(self, sel: np.ndarray) -> "_Readback":
        return _Readback(self.Rb[sel], self.vb[sel], self.omg[sel], self.wpos[sel], self.wvel[sel], self.q[sel],
                         self.qdot[sel])


def _rot(phi, theta, psi) -> np.ndarray:
    """R = Rz(psi) Ry(theta) Rx(phi) for arrays of angles -> (..., 3, 3)."""
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    return np.stack([np.stack([cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf], -1),
                     np.stack([sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf], -1),
                     np.stack([-st, ct * sf, ct * cf], -1)], -2)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross for (..., 3) arrays without its per-call overhead."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def _quat_to_mat(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _set_dynamics(body: int, link: int, inertia: list[float], cid: int) -> None:
    """No damping anywhere, no joint speed cap, the given principal inertia.

    Two calls on purpose: pybullet 3.2.7 drops ``localInertiaDiagonal`` (leaving zeros) when it
    is passed together with linearDamping, angularDamping or maxJointVelocity."""
    pb.changeDynamics(body, link, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0, maxJointVelocity=1e4,
                      physicsClientId=cid)
    pb.changeDynamics(body, link, localInertiaDiagonal=inertia, physicsClientId=cid)
    got = pb.getDynamicsInfo(body, link, physicsClientId=cid)[2]
    if not np.allclose(got, inertia, rtol=1e-9, atol=0.0):
        raise RuntimeError(f"pybullet did not take the inertia {inertia} of link {link} (has {got})")


class _Path:
    def __init__(self, polyline: np.ndarray, s0: float, speed: float) -> None:
        self.xy, self.psi, self.ds = resample_path(polyline)
        self.s0, self.v = float(s0), float(speed)

    def at_many(self, t: np.ndarray) -> np.ndarray:
        """(T, 6) of :meth:`at` for many times at once."""
        p, psi, dpsi = resampled_path_at(self.xy, self.psi, self.ds, self.s0 + self.v * np.asarray(t, dtype=np.float64))
        return np.column_stack([p, psi, dpsi * self.v, self.v * np.cos(psi), self.v * np.sin(psi)])

    def at(self, t: float):
        """(x, y, yaw, yaw rate, xdot, ydot) at time t."""
        s = self.s0 + self.v * t
        u = s / self.ds
        k = min(max(int(math.floor(u)), 0), len(self.xy) - 2)
        f = u - k
        p = self.xy[k] + (self.xy[k + 1] - self.xy[k]) * f
        fc = min(max(f, 0.0), 1.0)
        psi = self.psi[k] + (self.psi[k + 1] - self.psi[k]) * fc
        dpsi = (self.psi[k + 1] - self.psi[k]) / self.ds if 0.0 <= f <= 1.0 else 0.0
        return p[0], p[1], psi, dpsi * self.v, self.v * math.cos(psi), self.v * math.sin(psi)


class BulletVehicleSim:
    """Batched simulator over one static road mesh (numpy in, numpy out), same contract as the
    warp backend's ``VehicleSim``."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, chunk_triangles: int = MAX_MESH_TRIANGLES) -> None:
        self.cid = pb.connect(pb.DIRECT)
        self.vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if len(self.faces) == 0:
            raise ValueError("road mesh has no triangles")
        self.ztop = float(self.vertices[:, 2].max()) + 5.0
        t0 = time.perf_counter()
        self.road_ids = []
        # chunks grouped along the longer horizontal axis so each BVH is compact
        cent = self.vertices[self.faces].mean(axis=1)
        axis = int(np.argmax(np.ptp(cent[:, :2], axis=0)))
        order = np.argsort(cent[:, axis], kind="stable")
        chunk_triangles = min(int(chunk_triangles), MAX_MESH_TRIANGLES)
        lo = 0
        while lo < len(order):
            hi = min(lo + chunk_triangles, len(order))
            while True:
                f = self.faces[order[lo:hi]]
                used, inv = np.unique(f, return_inverse=True)
                if len(used) <= MAX_MESH_VERTICES:
                    break
                hi = lo + max(1, int((hi - lo) * 0.8 * MAX_MESH_VERTICES / len(used)))
            lo = hi
            col = pb.createCollisionShape(pb.GEOM_MESH, vertices=self.vertices[used].tolist(),
                                          indices=inv.reshape(-1).astype(int).tolist(),
                                          flags=pb.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=self.cid)
            if col < 0:
                raise RuntimeError("pybullet could not create the road collision mesh")
            self.road_ids.append(pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=col, physicsClientId=self.cid))
        self.build_s = time.perf_counter() - t0
        self.n_chunks = len(self.road_ids)

    def close(self) -> None:
        if self.cid is not None:
            pb.disconnect(self.cid)
            self.cid = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

    # ------------------------------------------------------------------ construction
    def _raycast(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """Hit fractions (1 where nothing is hit)."""
        out = np.ones(len(starts))
        for lo in range(0, len(starts), MAX_RAYS):
            res = pb.rayTestBatch(starts[lo: lo + MAX_RAYS].tolist(), ends[lo: lo + MAX_RAYS].tolist(),
                                  physicsClientId=self.cid)
            out[lo: lo + len(res)] = [r[2] if r[0] >= 0 else 1.0 for r in res]
        return out

    def _build_full(self, p: dict) -> int:
        c = self.cid
        corners = p["corners"]
        masses = [EPS_MASS] * 5 + [p["m_b"]] + [p["m_u"]] * 4
        types = [pb.JOINT_PRISMATIC, pb.JOINT_PRISMATIC, pb.JOINT_REVOLUTE, pb.JOINT_PRISMATIC, pb.JOINT_REVOLUTE,
                 pb.JOINT_REVOLUTE] + [pb.JOINT_PRISMATIC] * 4
        axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0]] + [[0, 0, 1]] * 4
        positions = [[0, 0, 0]] * 6 + [[k["x"], k["y"], -k["e_free"]] for k in corners]
        parents = [0, 1, 2, 3, 4, 5] + [6] * 4
        n = len(masses)
        body = pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=-1, basePosition=[0, 0, 0],
                                  linkMasses=masses, linkCollisionShapeIndices=[-1] * n,
                                  linkVisualShapeIndices=[-1] * n, linkPositions=positions,
                                  linkOrientations=[[0, 0, 0, 1]] * n, linkInertialFramePositions=[[0, 0, 0]] * n,
                                  linkInertialFrameOrientations=[[0, 0, 0, 1]] * n, linkParentIndices=parents,
                                  linkJointTypes=types, linkJointAxis=axes, physicsClientId=c)
        for j in range(n):
            inertia = [EPS_INERTIA] * 3
            if j == 5:
                inertia = [p["ixx"], p["iyy"], p["izz"]]
            _set_dynamics(body, j, inertia, c)
        pb.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=c)
        pb.setJointMotorControlArray(body, list(range(3, 10)), pb.VELOCITY_CONTROL, forces=[0.0] * 7,
                                     physicsClientId=c)
        return body

    def _build_quarter(self, p: dict) -> int:
        c = self.cid
        masses = [EPS_MASS, EPS_MASS, p["m_s"], p["m_u"]]
        body = pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=-1, basePosition=[0, 0, 0],
                                  linkMasses=masses, linkCollisionShapeIndices=[-1] * 4, linkVisualShapeIndices=[-1] * 4,
                                  linkPositions=[[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, -p["e_free"]]],
                                  linkOrientations=[[0, 0, 0, 1]] * 4, linkInertialFramePositions=[[0, 0, 0]] * 4,
                                  linkInertialFrameOrientations=[[0, 0, 0, 1]] * 4, linkParentIndices=[0, 1, 2, 3],
                                  linkJointTypes=[pb.JOINT_PRISMATIC] * 4,
                                  linkJointAxis=[[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1]], physicsClientId=c)
        for j in range(4):
            _set_dynamics(body, j, [1e-3] * 3, c)
        pb.setJointMotorControlArray(body, [2, 3], pb.VELOCITY_CONTROL, forces=[0.0, 0.0], physicsClientId=c)
        return body

    # ------------------------------------------------------------------ simulation
    def run(self, vehicles: list[dict], dt: float = 1e-3, imu_rate_hz: float = 500.0, tire_slices: int = 3,
            tire_arc_samples: int = 7, tire_arc_deg: float = 45.0, tire_refine: int = 2, lost_after_s: float = 1.0,
            initial_state: dict | None = None, **_ignored) -> dict:
        n = len(vehicles)
        if n == 0:
            raise ValueError("no vehicles")
        modes = {veh["params"].get("mode", "full") for veh in vehicles}
        if len(modes) != 1:
            raise ValueError("all vehicles of one run must share a mode (full or quarter)")
        mode = modes.pop()
        c = self.cid
        pb.setGravity(0, 0, -GRAVITY, physicsClientId=c)
        pb.setTimeStep(dt, physicsClientId=c)
        pb.setPhysicsEngineParameter(numSubSteps=0, physicsClientId=c)
        clock = _Clock.of(vehicles, dt, imu_rate_hz, lost_after_s)
        paths = [_Path(v["path"], v["s0"], v["speed"]) for v in vehicles]
        params = [v["params"] for v in vehicles]
        bodies = [self._build_full(p) if mode == "full" else self._build_quarter(p) for p in params]
        out = {k: np.full((n, clock.samples, d), np.nan) for k, d in (("acc", 3), ("gyro", 3), ("pose", 6),
                                                                       ("wheel_z", 4), ("tire_f", 4), ("susp", 4))}
        try:
            if mode == "full":
                rays = _TireRays.of(tire_slices, tire_arc_samples, tire_arc_deg, tire_refine)
                wall, dead, steps = self._run_full(bodies, params, paths, clock, rays, initial_state, out)
            else:
                wall, dead, steps = self._run_quarter(bodies, params, paths, clock, initial_state, out)
        finally:
            for b in bodies:
                pb.removeBody(b, physicsClientId=c)
        nsteps, imu_every = clock.nsteps, clock.imu_every
        out.update({"t": (np.arange(clock.samples) + 1) * imu_every * dt,
                    "valid": (nsteps // imu_every).astype(np.int64), "dead": dead, "steps": steps, "wall_s": wall,
                    "bvh_s": self.build_s, "sim_s": float((nsteps * dt).sum()), "imu_dt": imu_every * dt, "dt": dt,
                    "mode": mode})
        return out

    def _static_pose(self, p: dict, path: _Path):
        x, y, psi, wz, vx, vy = path.at(0.0)
        R0 = _rot(0.0, 0.0, psi)
        corners = p["corners"]
        xyw = np.array([[x, y, 0.0] + R0 @ np.array([k["x"], k["y"], 0.0]) for k in corners])
        starts = np.column_stack([xyw[:, :2], np.full(4, self.ztop)])
        ends = starts - np.array([0.0, 0.0, 1e4])
        frac = self._raycast(starts, ends)
        ok = bool((frac < 1.0).all())
        h = self.ztop - frac * 1e4
        wb = corners[0]["x"] - corners[2]["x"]
        hf, hr = h[:2].mean(), h[2:].mean()
        hcg = hr + (hf - hr) * (-corners[2]["x"]) / wb
        theta = -math.atan((hf - hr) / wb)
        tf = corners[0]["y"] - corners[1]["y"]
        tr = corners[2]["y"] - corners[3]["y"]
        phi = math.atan(0.5 * ((h[0] - h[1]) / tf + (h[2] - h[3]) / tr))
        return ok, hcg + p["cg_height"], phi, theta

    # ------------------------------------------------------------------ full vehicle
    def _run_full(self, bodies, params, paths, clock: "_Clock", rays: "_TireRays", initial_state, out):
        """Step every vehicle until its own end: read the states back, record the IMU, resolve
        the tire patches and the suspension forces, apply them, step Bullet."""
        n = len(bodies)
        nsteps, dt = clock.nsteps, clock.dt
        max_steps = int(nsteps.max())
        # the prescribed motion of every vehicle at every step: x, y, yaw, yaw rate, xdot, ydot
        presc = np.stack([path.at_many(np.arange(max_steps + 1) * dt) for path in paths])
        fleet = _FullFleet.of(params, rays.nl)
        st = _FullState.zeros(n)
        st.dead[:] = self._reset_full(bodies, params, paths, presc, initial_state)
        t_start = time.perf_counter()
        for k in range(max_steps + 1):
            # read back every vehicle still running or that has just made its last step
            steps = st.steps
            live = np.flatnonzero(~st.dead & (steps <= nsteps) & ((steps < nsteps) | (steps == k)))
            if len(live) == 0:
                break
            rb = self._read_full(bodies, live)
            self._record_full(st, fleet, live, rb, k, clock, out)
            run = st.steps[live] < nsteps[live]
            if not run.any():
                break
            sel = np.flatnonzero(run)
            act = live[sel]
            rb = rb.subset(sel)
            force, centres, f = self._tire_forces(fleet, act, rb, rays)
            spring = fleet.suspension_forces(act, rb.q[:, 6:10], rb.qdot[:, 6:10])
            tire_tot = f.sum(-1)
            st.last_tire = {i: tire_tot[a] for a, i in enumerate(act)}
            nowheel = (tire_tot <= 0.0).any(axis=1)
            st.lost[act] = np.where(nowheel, st.lost[act] + 1, 0)
            self._apply_full(bodies, act, presc, k, spring, force, centres, f > 0.0, rays.nl)
            st.dead[act] |= st.lost[act] > clock.lost_limit
            pb.stepSimulation(physicsClientId=self.cid)
            st.steps[act] += 1
        return time.perf_counter() - t_start, st.dead, st.steps

    def _reset_full(self, bodies, params, paths, presc, initial_state) -> np.ndarray:
        """Every joint at the static pose over the road (or the given initial state); returns
        which vehicles have no road under a wheel."""
        init = initial_state or {}
        dead = np.zeros(len(bodies), dtype=bool)
        for i, (b, p, path) in enumerate(zip(bodies, params, paths)):
            ok, z, phi, theta = self._static_pose(p, path)
            dead[i] = not ok
            s = [k["s_static"] for k in p["corners"]]
            qd = [0.0, 0.0, 0.0]
            sd = [0.0] * 4
            if i in init:
                z, phi, theta = init[i].get("q", (z, phi, theta))
                qd = list(init[i].get("qd", qd))
                s = list(init[i].get("s", s))
                sd = list(init[i].get("sd", sd))
            x, y, psi, wz, vx, vy = presc[i, 0]
            for j, (pos, vel) in enumerate(zip([x, y, psi, z, theta, phi] + list(s),
                                               [vx, vy, wz, qd[0], qd[2], qd[1]] + list(sd))):
                pb.resetJointState(b, j, float(pos), float(vel), physicsClientId=self.cid)
        return dead

    def _read_full(self, bodies, live: np.ndarray) -> "_Readback":
        """Body rotation, velocities, wheel positions/velocities and joint states of ``live``."""
        c = self.cid
        A = len(live)
        rb = _Readback(Rb=np.empty((A, 3, 3)), vb=np.empty((A, 3)), omg=np.empty((A, 3)), wpos=np.empty((A, 4, 3)),
                       wvel=np.empty((A, 4, 3)), q=np.empty((A, 10)), qdot=np.empty((A, 10)))
        for a, i in enumerate(live):
            ls = pb.getLinkStates(bodies[i], BODY_AND_WHEEL_LINKS, computeLinkVelocity=1, computeForwardKinematics=1,
                                  physicsClientId=c)
            rb.Rb[a] = _quat_to_mat(ls[0][5])
            rb.vb[a] = ls[0][6]
            rb.omg[a] = ls[0][7]
            rb.wpos[a] = [l_[4] for l_ in ls[1:]]
            rb.wvel[a] = [l_[6] for l_ in ls[1:]]
            js = pb.getJointStates(bodies[i], range(10), physicsClientId=c)
            rb.q[a] = [j_[0] for j_ in js]
            rb.qdot[a] = [j_[1] for j_ in js]
        return rb

    @staticmethod
    def _record_full(st: "_FullState", fleet: "_FullFleet", live, rb: "_Readback", k: int, clock: "_Clock",
                     out: dict) -> None:
        """IMU: finite difference of the IMU point's velocity, into the body frame; an output
        sample at the end of each IMU interval."""
        dt, imu_every = clock.dt, clock.imu_every
        vimu = rb.vb + _cross(rb.omg, np.einsum("aij,aj->ai", rb.Rb, fleet.r_imu[live]))
        if k > 0:
            stepped = st.steps[live] > 0
            li = live[stepped]
            st.acc_sum[li] += np.einsum("aji,aj->ai", rb.Rb[stepped], (vimu[stepped] - st.vimu_prev[li]) / dt + GZ)
            st.gyro_sum[li] += np.einsum("aji,aj->ai", rb.Rb[stepped], rb.omg[stepped])
            due = stepped & (st.steps[live] % imu_every == 0)
            for a in np.flatnonzero(due):
                i = live[a]
                kk = st.steps[i] // imu_every - 1
                out["acc"][i, kk] = st.acc_sum[i] / imu_every
                out["gyro"][i, kk] = st.gyro_sum[i] / imu_every
                st.acc_sum[i] = 0.0
                st.gyro_sum[i] = 0.0
                out["pose"][i, kk] = rb.q[a, POSE_FROM_JOINTS]
                out["wheel_z"][i, kk] = rb.wpos[a, :, 2]
                out["tire_f"][i, kk] = st.last_tire[i]
                out["susp"][i, kk] = rb.q[a, 6:10] - fleet.sstat[i]
        st.vimu_prev[live] = vimu

    def _tire_forces(self, fleet: "_FullFleet", act, rb: "_Readback", rays: "_TireRays"):
        """Each tire slice's radial spring-damper force (world frame) from its deepest arc ray,
        refined by bisection rounds as the warp backend does; returns (forces (A,4,nl,3) as
        lists, slice centres (A,4,nl,3) as lists, force magnitudes (A,4,nl))."""
        nl, na, arc = rays.nl, rays.na, rays.arc
        A = len(act)
        Rb, wpos, wvel, omg = rb.Rb, rb.wpos, rb.wvel, rb.omg
        radius = fleet.radius[act]
        lat = Rb[:, :, 1]
        dirs = np.einsum("aij,kj->aki", Rb, rays.dirs_b)                                   # (A, na, 3)
        centres = wpos[:, :, None, :] + lat[:, None, None, :] * fleet.yoff[act][:, None, :, None]  # (A,4,nl,3)
        starts = np.broadcast_to(centres[:, :, :, None, :], (A, 4, nl, na, 3))
        ends = starts + dirs[:, None, None, :, :] * radius[:, None, None, None, None]
        frac = self._raycast(starts.reshape(-1, 3), ends.reshape(-1, 3)).reshape(A, 4, nl, na)
        pen = (1.0 - frac) * radius[:, None, None, None]
        best = pen.argmax(axis=-1)                                                         # (A,4,nl)
        depth = np.take_along_axis(pen, best[..., None], -1)[..., 0]
        # bisection rounds around the deepest ray (as the warp backend: two rays a round)
        alpha_s = rays.alpha[best]
        has = depth > 0.0
        h = 0.5 * rays.step_a
        rad3 = np.broadcast_to(radius[:, None, None], depth.shape)
        for _ in range(rays.refine):
            if h > 0.0 and has.any():
                idx = np.nonzero(has)
                a_lo = np.maximum(alpha_s[idx] - h, -arc)
                a_hi = np.minimum(alpha_s[idx] + h, arc)
                Rsel = Rb[idx[0]]
                o = centres[idx]
                dl = np.einsum("aij,aj->ai", Rsel, np.stack([np.sin(a_lo), 0 * a_lo, -np.cos(a_lo)], -1))
                dh = np.einsum("aij,aj->ai", Rsel, np.stack([np.sin(a_hi), 0 * a_hi, -np.cos(a_hi)], -1))
                rr = rad3[idx][:, None]
                fr = self._raycast(np.concatenate([o, o]), np.concatenate([o + dl * rr, o + dh * rr]))
                p_lo = (1.0 - fr[: len(o)]) * rr[:, 0]
                p_hi = (1.0 - fr[len(o):]) * rr[:, 0]
                dep, al = depth[idx], alpha_s[idx]
                up = p_lo > dep
                dep, al = np.where(up, p_lo, dep), np.where(up, a_lo, al)
                up = p_hi > dep
                dep, al = np.where(up, p_hi, dep), np.where(up, a_hi, al)
                depth[idx], alpha_s[idx] = dep, al
            h *= 0.5
        d = np.einsum("aij,awlj->awli", Rb, np.stack([np.sin(alpha_s), 0 * alpha_s, -np.cos(alpha_s)], -1))
        vs = wvel[:, :, None, :] + _cross(np.broadcast_to(omg[:, None, None, :], centres.shape),
                                          centres - wpos[:, :, None, :])
        rate = (vs * d).sum(-1)
        f = np.where(depth > 0, np.maximum((fleet.kt[act, None, None] * depth + fleet.ct[act, None, None] * rate) / nl,
                                           0.0), 0.0)
        return (-d * f[..., None]).tolist(), centres.tolist(), f

    def _apply_full(self, bodies, act, presc, k: int, spring, force, centres, contact, nl: int) -> None:
        """Hold x, y, yaw on the path for this step, drive the suspension joints, push the
        wheels with the tire slices that touch the road."""
        c = self.cid
        x0, y0, psi0, wz0, vx0, vy0 = presc[act, k].T
        vx1, vy1, wz1 = presc[act, k + 1, 4], presc[act, k + 1, 5], presc[act, k + 1, 3]
        kin_q = np.column_stack([x0, y0, psi0])[:, :, None].tolist()
        kin_v = np.column_stack([vx0, vy0, wz0])[:, :, None].tolist()
        kin_v1 = np.column_stack([vx1, vy1, wz1]).tolist()
        spring = spring.tolist()
        for a, i in enumerate(act):
            b = bodies[i]
            pb.resetJointStatesMultiDof(b, PATH_JOINTS, kin_q[a], kin_v[a], physicsClientId=c)
            pb.setJointMotorControlArray(b, PATH_JOINTS, pb.VELOCITY_CONTROL, targetVelocities=kin_v1[a],
                                         forces=[KINEMATIC_FORCE] * 3, physicsClientId=c)
            pb.setJointMotorControlArray(b, SUSPENSION_JOINTS, pb.TORQUE_CONTROL, forces=spring[a], physicsClientId=c)
            fa, ca, con = force[a], centres[a], contact[a]
            for w in range(4):
                for sl in range(nl):
                    if con[w, sl]:
                        pb.applyExternalForce(b, SUSPENSION_JOINTS[w], fa[w][sl], ca[w][sl], pb.WORLD_FRAME,
                                              physicsClientId=c)

    # ------------------------------------------------------------------ quarter car
    def _run_quarter(self, bodies, params, paths, clock: _Clock, initial_state, out):
        c = self.cid
        nsteps, dt, imu_every, lost_limit = clock.nsteps, clock.dt, clock.imu_every, clock.lost_limit
        n = len(bodies)
        dead = np.zeros(n, dtype=bool)
        lost = np.zeros(n, dtype=np.int64)
        steps = np.zeros(n, dtype=np.int64)
        vprev = np.zeros(n)
        acc_sum = np.zeros(n)
        last_ft = np.zeros(n)
        init = initial_state or {}
        for i, (b, p, path) in enumerate(zip(bodies, params, paths)):
            x, y, psi, wz, vx, vy = path.at(0.0)
            frac = self._raycast(np.array([[x, y, self.ztop]]), np.array([[x, y, self.ztop - 1e4]]))
            dead[i] = frac[0] >= 1.0
            h = self.ztop - frac[0] * 1e4
            zu = h + p["radius"] - (p["m_s"] + p["m_u"]) * GRAVITY / p["kt"]
            zs = zu + p["e_free"] - p["s_static"]
            s, zsd, sd = p["s_static"], 0.0, 0.0
            if i in init:
                zs, zu_ = init[i]["q"][:2]
                zsd, zud = init[i].get("qd", (0.0, 0.0, 0.0))[:2]
                s, sd = p["e_free"] - (zs - zu_), zud - zsd
            for j, (pos, vel) in enumerate(zip([x, y, zs, s], [vx, vy, zsd, sd])):
                pb.resetJointState(b, j, float(pos), float(vel), physicsClientId=c)
            vprev[i] = zsd
        t_start = time.perf_counter()
        for k in range(int(nsteps.max())):
            active = np.flatnonzero(~dead & (steps < nsteps))
            if len(active) == 0:
                break
            t = k * dt
            st = [pb.getLinkState(bodies[i], 3, computeLinkVelocity=1, computeForwardKinematics=1, physicsClientId=c) for i in active]
            js = [pb.getJointState(bodies[i], 3, physicsClientId=c) for i in active]
            wpos = np.array([s_[4] for s_ in st])
            wvel = np.array([s_[6] for s_ in st])
            radius = np.array([params[i]["radius"] for i in active])
            frac = self._raycast(wpos, wpos - np.column_stack([np.zeros((len(active), 2)), radius]))
            pen = (1.0 - frac) * radius
            for a, i in enumerate(active):
                p = params[i]
                b = bodies[i]
                ft = max(p["kt"] * pen[a] - p["ct"] * wvel[a, 2], 0.0) if pen[a] > 0 else 0.0
                s, sd = js[a][0], js[a][1]
                x, y, psi, wz, vx, vy = paths[i].at(t)
                pb.resetJointState(b, 0, x, vx, physicsClientId=c)
                pb.resetJointState(b, 1, y, vy, physicsClientId=c)
                _, _, _, _, vx1, vy1 = paths[i].at(t + dt)
                pb.setJointMotorControlArray(b, [0, 1], pb.VELOCITY_CONTROL, targetVelocities=[vx1, vy1],
                                             forces=[KINEMATIC_FORCE] * 2, physicsClientId=c)
                pb.setJointMotorControl2(b, 3, pb.TORQUE_CONTROL, force=-(p["ks"] * s + p["cs"] * sd), physicsClientId=c)
                if ft > 0:
                    pb.applyExternalForce(b, 3, [0.0, 0.0, ft], wpos[a].tolist(), pb.WORLD_FRAME, physicsClientId=c)
                    lost[i] = 0
                else:
                    lost[i] += 1
                    dead[i] = lost[i] > lost_limit
                last_ft[i] = ft
            pb.stepSimulation(physicsClientId=c)
            steps[active] += 1
            for i in active:
                b = bodies[i]
                jz = pb.getJointState(b, 2, physicsClientId=c)
                acc_sum[i] += (jz[1] - vprev[i]) / dt + GRAVITY
                vprev[i] = jz[1]
                if steps[i] % imu_every == 0:
                    kk = steps[i] // imu_every - 1
                    out["acc"][i, kk] = [0.0, 0.0, acc_sum[i] / imu_every]
                    out["gyro"][i, kk] = 0.0
                    acc_sum[i] = 0.0
                    q = [s_[0] for s_ in pb.getJointStates(b, [0, 1, 2, 3], physicsClientId=c)]
                    out["pose"][i, kk] = [q[0], q[1], q[2], 0.0, 0.0, 0.0]
                    zw = pb.getLinkState(b, 3, computeForwardKinematics=1, physicsClientId=c)[4][2]
                    out["wheel_z"][i, kk] = [zw, 0.0, 0.0, 0.0]
                    out["tire_f"][i, kk] = [last_ft[i], 0.0, 0.0, 0.0]
                    out["susp"][i, kk] = [q[3] - params[i]["s_static"], 0.0, 0.0, 0.0]
        return time.perf_counter() - t_start, dead, steps
