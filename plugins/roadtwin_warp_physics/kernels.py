"""Tire-level vehicle dynamics on warp: N vehicles per launch over one road triangle mesh.

Standalone on purpose: this file imports numpy and warp only, so ``bench/sweep.py`` can load it
by path on a GPU machine that has neither USD nor pybullet nor roadtwin. The roadtwin plugin
(``__init__.py``) adapts roadtwin's types to :class:`VehicleSim`.

Model (the same as the pybullet backend's; see ``roadtwin_core/vehicle/vehicle.py`` for the
parameters):

* Generalised coordinates per full vehicle: body heave z, roll phi, pitch theta and the four
  suspension compressions s_i. The body pose has 6 DOF, R = Rz(psi) Ry(theta) Rx(phi); x, y and
  yaw psi are *rheonomic* (kinematically prescribed): the CG moves along the vehicle's path at
  constant speed with the path heading (the constraint forces that hold speed and lane are not
  computed; they are whatever the tires' longitudinal/lateral forces and inertia demand).
* Equations of motion: projected Newton-Euler (Kane) for the body (rigid, principal inertias)
  and four wheel point masses that slide along the body z axis and turn with the body. The
  unsprung masses couple to heave/roll/pitch through the generalised mass matrix; the 7x7
  system is solved by eliminating the (diagonal) wheel block, leaving a 3x3 solve.
* Suspension: linear spring (free at s = 0) + linear damper + stiff stops past the travel
  limits (stop forces never pull).
* Tires: radial springs with damping. Each tire is cut into ``tire_slices`` lateral slices;
  for each slice ``tire_arc_samples`` rays leave the slice centre over the lower arc
  (+-``tire_arc_deg`` about straight down, in the wheel plane, which turns with the body) and
  are cast against the road mesh with ``wp.mesh_query_ray`` up to the tire radius; then
  ``tire_refine`` bisection rounds (two rays each, the bracket halving) home in on the deepest
  direction around the deepest ray (a pothole's rim is a sharp maximum between two rays). A
  slice's penetration is that deepest (radius - hit distance), its force
  ``(kt delta + ct delta_dot) / slices`` along the ray back towards the wheel centre, never
  negative (lift-off). So a tire partly over a pothole carries its load on the slices still on
  the road, a wheel in a pothole is pushed back and up by the far edge, and on flat ground the
  tire is a linear spring of stiffness kt (the straight-down ray is the deepest). Default
  3 x (7 + 2 x 2) = 33 rays per tire. Sampling sensitivity on the reference potholes (peak g at
  10/30/50 km/h): 3x7+2 is within 4 % of 9x41+3 on the 1.2 m x 8 cm pothole and within 13 % on
  the 0.3 m x 2.5 cm one (without the bisection rounds 3x7 was 23 % off there).
* Integration: semi-implicit (symplectic) Euler with a fixed dt (1 ms default), float32.
* IMU (at a body-fixed point): each sample is the mean over its interval of the specific force
  (acceleration minus gravity, body frame, from the finite difference of the IMU point's world
  velocity, i.e. a delta-velocity IMU) and of the body-frame angular rate.

Quarter car mode: sprung mass on spring+damper over an unsprung mass with a point-follower tire
(one vertical ray under the wheel centre), for validation against closed forms.

Launch layout: on CUDA, per step one launch resolves every tire slice of every vehicle (one
thread per slice: its rays, its force) and one integrates every vehicle (one thread per
vehicle); chunks of steps are captured into a CUDA graph. On CPU one launch integrates
``steps_per_launch`` steps of every vehicle, contacts inline. The BVH is built with the SAH
constructor: on a 1.6 M-triangle town it traced these short rays 5-9x faster than warp's
default LBVH on an H200. No atomics anywhere: results are deterministic.
"""
import math
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

GRAVITY = 9.81

# Packed parameter row of a full vehicle (float32): body, tire, then 4 corners of 8.
P_MB, P_IXX, P_IYY, P_IZZ, P_MU, P_R, P_W, P_KT, P_CT, P_KSTOP, P_CSTOP, P_IMUX, P_IMUY, P_IMUZ, P_CGH = range(15)
P_CORNER0, P_CSTRIDE = 16, 8
C_X, C_Y, C_EFREE, C_KS, C_CS, C_SMIN, C_SMAX, C_SSTAT = range(8)
NP = P_CORNER0 + 4 * P_CSTRIDE
# Quarter car row.
Q_MS, Q_MU, Q_KS, Q_CS, Q_KT, Q_CT, Q_R, Q_EFREE, Q_SSTAT = range(9)

_P = {k: wp.constant(v) for k, v in dict(
    MB=P_MB, IXX=P_IXX, IYY=P_IYY, IZZ=P_IZZ, MU=P_MU, R=P_R, W=P_W, KT=P_KT, CT=P_CT, KSTOP=P_KSTOP,
    CSTOP=P_CSTOP, IMUX=P_IMUX, IMUY=P_IMUY, IMUZ=P_IMUZ, CGH=P_CGH, C0=P_CORNER0, CS=P_CSTRIDE).items()}
PMB, PIXX, PIYY, PIZZ, PMU, PR, PW, PKT, PCT = (_P[k] for k in ("MB", "IXX", "IYY", "IZZ", "MU", "R", "W", "KT", "CT"))
PKSTOP, PCSTOP, PIMUX, PIMUY, PIMUZ, PCGH, PC0, PCSTRIDE = (_P[k] for k in ("KSTOP", "CSTOP", "IMUX", "IMUY", "IMUZ",
                                                                          "CGH", "C0", "CS"))
GRAV = wp.constant(GRAVITY)

# Compile time (issue #12): nothing here is differentiated, so no backward pass (it more than
# doubled the generated code); and each kernel is its own warp module, so a launch compiles that
# kernel alone, for the block size it is launched with (one shared module was compiled whole,
# every kernel with it, once per block size used: 256, 128 and 32 on CUDA).
wp.set_module_options({"enable_backward": False})
_NO_GRAD = {"enable_backward": False}


def kernel(f):
    """``wp.kernel`` in a module of its own, forward only."""
    return wp.kernel(f, enable_backward=False, module="unique", module_options=_NO_GRAD)


def quiet() -> None:
    """No init banner or per-module load lines (warnings still show)."""
    if hasattr(wp.config, "log_level") and hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    else:  # older warp
        wp.config.quiet = True


def pack_vehicle(p: dict) -> np.ndarray:
    """Plain vehicle dict (``VehicleParams.to_plain()``) -> packed float row."""
    row = np.zeros(NP, dtype=np.float64)
    if p.get("mode", "full") == "quarter":
        row[[Q_MS, Q_MU, Q_KS, Q_CS, Q_KT, Q_CT, Q_R, Q_EFREE, Q_SSTAT]] = [
            p["m_s"], p["m_u"], p["ks"], p["cs"], p["kt"], p["ct"], p["radius"], p["e_free"], p["s_static"]]
        return row
    row[[P_MB, P_IXX, P_IYY, P_IZZ, P_MU, P_R, P_W, P_KT, P_CT, P_KSTOP, P_CSTOP]] = [
        p["m_b"], p["ixx"], p["iyy"], p["izz"], p["m_u"], p["radius"], p["width"], p["kt"], p["ct"],
        p["k_stop"], p["c_stop"]]
    row[[P_IMUX, P_IMUY, P_IMUZ]] = p["imu"]
    row[P_CGH] = p["cg_height"]
    for i, c in enumerate(p["corners"]):
        b = P_CORNER0 + i * P_CSTRIDE
        row[b:b + 8] = [c["x"], c["y"], c["e_free"], c["ks"], c["cs"], c["s_min"], c["s_max"], c["s_static"]]
    return row


def max_stable_dt(p: dict) -> float:
    """A conservative step limit: the stiffest wheel mode must satisfy omega dt < 0.5."""
    if p.get("mode", "full") == "quarter":
        k = p["kt"] + p["ks"]
    else:
        k = p["kt"] + p["k_stop"] + max(c["ks"] for c in p["corners"])
    return 0.5 / math.sqrt(k / p["m_u"])


@wp.struct
class Fleet:
    """Per-vehicle constants."""
    params: wp.array2d(dtype=wp.float32)
    pidx: wp.array(dtype=wp.int32)
    path_xy: wp.array(dtype=wp.vec2)
    path_psi: wp.array(dtype=wp.float32)
    path_off: wp.array(dtype=wp.int32)
    path_n: wp.array(dtype=wp.int32)
    path_ds: wp.array(dtype=wp.float32)
    s0: wp.array(dtype=wp.float32)
    speed: wp.array(dtype=wp.float32)
    nsteps: wp.array(dtype=wp.int32)


@wp.struct
class State:
    q: wp.array(dtype=wp.vec3)      # full: (z, roll, pitch); quarter: (z_body, z_wheel, 0)
    qd: wp.array(dtype=wp.vec3)
    s: wp.array(dtype=wp.vec4)      # suspension compressions (full)
    sd: wp.array(dtype=wp.vec4)
    step: wp.array(dtype=wp.int32)
    vimu: wp.array(dtype=wp.vec3)   # IMU point world velocity at the previous step
    acc_sum: wp.array(dtype=wp.vec3)
    gyro_sum: wp.array(dtype=wp.vec3)
    lost: wp.array(dtype=wp.int32)  # consecutive steps with a wheel off the road
    dead: wp.array(dtype=wp.int32)  # 1: left the mesh (a wheel without contact for too long)


@wp.struct
class Output:
    acc: wp.array2d(dtype=wp.vec3)
    gyro: wp.array2d(dtype=wp.vec3)
    pose: wp.array2d(dtype=wp.vec3)   # (z, roll, pitch)
    wheel_z: wp.array2d(dtype=wp.vec4)
    tire_f: wp.array2d(dtype=wp.vec4)
    susp: wp.array2d(dtype=wp.vec4)   # compression relative to static


@wp.struct
class Config:
    dt: wp.float32
    imu_every: wp.int32
    nl: wp.int32          # tire slices
    na: wp.int32          # arc samples per slice
    arc: wp.float32       # half angle of the sampled arc (rad)
    refine: wp.int32      # bisection rounds around the deepest arc ray (2 rays each)
    lost_limit: wp.int32  # steps


# ----------------------------------------------------------------------------- geometry
@wp.func
def path_eval(fl: Fleet, i: int, s: float):
    off = fl.path_off[i]
    n = fl.path_n[i]
    ds = fl.path_ds[i]
    u = s / ds
    k = wp.clamp(int(wp.floor(u)), 0, n - 2)
    f = u - float(k)
    p0 = fl.path_xy[off + k]
    p1 = fl.path_xy[off + k + 1]
    xy = p0 + (p1 - p0) * f
    fc = wp.clamp(f, 0.0, 1.0)
    a0 = fl.path_psi[off + k]
    a1 = fl.path_psi[off + k + 1]
    psi = a0 + (a1 - a0) * fc
    dpsi = (a1 - a0) / ds
    if f < 0.0 or f > 1.0:
        dpsi = 0.0
    return xy, psi, dpsi


@wp.func
def euler_rot(phi: float, theta: float, psi: float):
    cf = wp.cos(phi)
    sf = wp.sin(phi)
    ct = wp.cos(theta)
    st = wp.sin(theta)
    cp = wp.cos(psi)
    sp = wp.sin(psi)
    return wp.mat33(cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf,
                    sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf,
                    -st, ct * sf, ct * cf)


@wp.func
def corner_base(c: int):
    return PC0 + c * PCSTRIDE


@wp.func
def pose_of(fl: Fleet, st: State, i: int, dt: float, step: int):
    """World CG position, rotation, yaw rate and speed at a step (path at time step*dt)."""
    v = fl.speed[i]
    t = float(step) * dt
    xy, psi, dpsi = path_eval(fl, i, fl.s0[i] + v * t)
    q = st.q[i]
    R = euler_rot(q[1], q[2], psi)
    return wp.vec3(xy[0], xy[1], q[0]), R, psi, dpsi * v


@wp.func
def cast(mesh: wp.uint64, origin: wp.vec3, d: wp.vec3, radius: float):
    h = wp.mesh_query_ray(mesh, origin, d, radius)
    t = radius
    if h.result:
        t = h.t
    return t


@wp.func
def body_rates(fl: Fleet, st: State, i: int, psi: float, wz: float):
    """Body-frame angular velocity and body-frame CG velocity of vehicle i."""
    q = st.q[i]
    qd = st.qd[i]
    cf = wp.cos(q[1])
    sf = wp.sin(q[1])
    ct = wp.cos(q[2])
    st_ = wp.sin(q[2])
    e1 = wp.vec3(0.0, cf, -sf)
    e2 = wp.vec3(-st_, sf * ct, cf * ct)
    omega = wp.vec3(qd[1], 0.0, 0.0) + e1 * qd[2] + e2 * wz
    v = fl.speed[i]
    return omega, wp.vec3(wp.cos(psi) * v, wp.sin(psi) * v, qd[0])


@wp.func
def slice_contact(mesh: wp.uint64, fl: Fleet, st: State, cfg: Config, i: int, j: int, p: wp.vec3, R: wp.mat33,
                  omega: wp.vec3, v_cg: wp.vec3):
    """Tire slice j (= wheel * slices + slice) of vehicle i: cast its arc rays, take the deepest
    penetration, return (force on the wheel in the body frame, its magnitude) as a vec4."""
    pi = fl.pidx[i]
    nl = cfg.nl
    na = cfg.na
    c = j / nl
    sl = j - c * nl
    b = corner_base(c)
    radius = fl.params[pi, PR]
    yoff = fl.params[pi, PW] * ((float(sl) + 0.5) / float(nl) - 0.5)
    sc = st.s[i]
    r = wp.vec3(fl.params[pi, b + 0], fl.params[pi, b + 1], -fl.params[pi, b + 2] + sc[c])
    rs = wp.vec3(0.0, yoff, 0.0)
    origin = p + R * (r + rs)
    # penetrations along the sampled arc; around the deepest one a bisection search (two more rays
    # per round, the bracket halves) homes in on the deepest direction, e.g. a pothole's rim
    step_a = float(0.0)
    if na > 1:
        step_a = 2.0 * cfg.arc / float(na - 1)
    best = float(0.0)
    bestk = int(-1)
    for k in range(na):
        alpha = -cfg.arc + step_a * float(k)
        dpen = radius - cast(mesh, origin, R * wp.vec3(wp.sin(alpha), 0.0, -wp.cos(alpha)), radius)
        if dpen > best:
            best = dpen
            bestk = k
    out = wp.vec4()
    if bestk >= 0:
        alpha = -cfg.arc + step_a * float(bestk)
        h = 0.5 * step_a
        for _r in range(cfg.refine):
            if h > 0.0:
                a_lo = wp.max(alpha - h, -cfg.arc)
                a_hi = wp.min(alpha + h, cfg.arc)
                p_lo = radius - cast(mesh, origin, R * wp.vec3(wp.sin(a_lo), 0.0, -wp.cos(a_lo)), radius)
                p_hi = radius - cast(mesh, origin, R * wp.vec3(wp.sin(a_hi), 0.0, -wp.cos(a_hi)), radius)
                if p_lo > best:
                    best = p_lo
                    alpha = a_lo
                if p_hi > best:
                    best = p_hi
                    alpha = a_hi
            h = 0.5 * h
        d = wp.vec3(wp.sin(alpha), 0.0, -wp.cos(alpha))
        sd = st.sd[i]
        vs = wp.transpose(R) * v_cg + wp.cross(omega, r + rs) + wp.vec3(0.0, 0.0, sd[c])
        rate = wp.dot(vs, d)
        f = wp.max((fl.params[pi, PKT] * best + fl.params[pi, PCT] * rate) / float(nl), 0.0)
        out = wp.vec4(-d[0] * f, -d[1] * f, -d[2] * f, f)
    return out


@kernel
def contact_kernel(mesh: wp.uint64, fl: Fleet, st: State, cfg: Config, slices: wp.array2d(dtype=wp.vec4)):
    """One thread per tire slice of every vehicle."""
    i, j = wp.tid()
    if st.dead[i] != 0 or st.step[i] >= fl.nsteps[i]:
        return
    p, R, psi, wz = pose_of(fl, st, i, cfg.dt, st.step[i])
    omega, v_cg = body_rates(fl, st, i, psi, wz)
    slices[i, j] = slice_contact(mesh, fl, st, cfg, i, j, p, R, omega, v_cg)


# ----------------------------------------------------------------------------- dynamics
@wp.func
def stop_force(s: float, sd: float, smin: float, smax: float, k: float, c: float):
    f = float(0.0)
    if s > smax:
        f = wp.max(k * (s - smax) + c * sd, 0.0)
    elif s < smin:
        f = wp.min(k * (s - smin) + c * sd, 0.0)
    return f


@wp.func
def imu_velocity(p_vel: wp.vec3, R: wp.mat33, omega_b: wp.vec3, r_imu: wp.vec3):
    return p_vel + R * wp.cross(omega_b, r_imu)


@wp.func
def advance_full(fl: Fleet, st: State, cfg: Config, out: Output, i: int, slices: wp.array2d(dtype=wp.vec4)):
    pi = fl.pidx[i]
    dt = cfg.dt
    step = st.step[i]
    v = fl.speed[i]
    p, R, psi, wz = pose_of(fl, st, i, dt, step)
    q = st.q[i]
    qd = st.qd[i]
    s = st.s[i]
    sd = st.sd[i]
    phi = q[1]
    th = q[2]
    cf = wp.cos(phi)
    sf = wp.sin(phi)
    ct = wp.cos(th)
    stt = wp.sin(th)
    e0 = wp.vec3(1.0, 0.0, 0.0)
    e1 = wp.vec3(0.0, cf, -sf)
    e2 = wp.vec3(-stt, sf * ct, cf * ct)       # = R^T e_z (world up in the body frame)
    omega = e0 * qd[1] + e1 * qd[2] + e2 * wz
    edq = wp.vec3(-ct * qd[2] * wz,
                  -sf * qd[1] * qd[2] + (cf * ct * qd[1] - sf * stt * qd[2]) * wz,
                  -cf * qd[1] * qd[2] + (-sf * ct * qd[1] - cf * stt * qd[2]) * wz)
    alpha0 = edq                               # psi_ddot = 0 on each path piece
    tang = wp.vec3(wp.cos(psi), wp.sin(psi), 0.0)
    left = wp.vec3(-wp.sin(psi), wp.cos(psi), 0.0)
    a_h = wp.transpose(R) * (left * (v * wz))    # prescribed (centripetal) CG acceleration, body frame
    v_cg = tang * v + wp.vec3(0.0, 0.0, qd[0])
    mb = fl.params[pi, PMB]
    mu = fl.params[pi, PMU]
    inertia = wp.vec3(fl.params[pi, PIXX], fl.params[pi, PIYY], fl.params[pi, PIZZ])
    width = fl.params[pi, PW]
    kstop = fl.params[pi, PKSTOP]
    cstop = fl.params[pi, PCSTOP]
    ez = wp.vec3(0.0, 0.0, 1.0)
    # body block of the generalised mass matrix and forces (coordinates z, phi, theta)
    Iw = wp.cw_mul(inertia, omega)
    bias = wp.cw_mul(inertia, alpha0) + wp.cross(omega, Iw)
    Ie1 = wp.cw_mul(inertia, e1)
    A = wp.mat33(mb, 0.0, 0.0,
                 0.0, inertia[0], wp.dot(e0, Ie1),
                 0.0, wp.dot(e0, Ie1), wp.dot(e1, Ie1))
    Qb = wp.vec3(-mb * GRAV, -wp.dot(e0, bias), -wp.dot(e1, bias))
    Qs = wp.vec4()
    cpl0 = wp.vec3()
    cpl1 = wp.vec3()
    cpl2 = wp.vec3()
    cpl3 = wp.vec3()
    tire_tot = wp.vec4()
    wheel_z = wp.vec4()
    any_lost = int(0)
    nl = cfg.nl
    for c in range(4):
        b = corner_base(c)
        ks = fl.params[pi, b + 3]
        cs = fl.params[pi, b + 4]
        r = wp.vec3(fl.params[pi, b + 0], fl.params[pi, b + 1], -fl.params[pi, b + 2] + s[c])
        jz = e2
        jf = wp.cross(e0, r)
        jt = wp.cross(e1, r)
        # wheel contributions to the mass matrix (point mass, body-frame Jacobian columns)
        A = A + mu * wp.mat33(wp.dot(jz, jz), wp.dot(jz, jf), wp.dot(jz, jt),
                              wp.dot(jf, jz), wp.dot(jf, jf), wp.dot(jf, jt),
                              wp.dot(jt, jz), wp.dot(jt, jf), wp.dot(jt, jt))
        cpl = mu * wp.vec3(wp.dot(jz, ez), wp.dot(jf, ez), wp.dot(jt, ez))
        # wheel bias acceleration (body frame)
        a0 = a_h + wp.cross(alpha0, r) + wp.cross(omega, wp.cross(omega, r)) + 2.0 * wp.cross(omega, ez * sd[c])
        # tire: the slices' radial forces (contact stage), their moment about the wheel centre
        Fw = wp.vec3()       # total tire force on this wheel, body frame
        tau = wp.vec3()      # moment of the slice forces about the wheel centre, body frame
        ftot = float(0.0)
        for sl in range(nl):
            fs4 = slices[i, c * nl + sl]
            Fs = wp.vec3(fs4[0], fs4[1], fs4[2])
            rs = wp.vec3(0.0, width * ((float(sl) + 0.5) / float(nl) - 0.5), 0.0)
            Fw = Fw + Fs
            tau = tau + wp.cross(rs, Fs)
            ftot = ftot + fs4[3]
        if ftot <= 0.0:
            any_lost = 1
        tire_tot[c] = ftot
        Fext = Fw - e2 * (mu * GRAV) - a0 * mu          # external + inertial bias force on the wheel
        ssp = ks * s[c] + cs * sd[c] + stop_force(s[c], sd[c], fl.params[pi, b + 5], fl.params[pi, b + 6],
                                                   kstop, cstop)
        Qb = Qb + wp.vec3(wp.dot(jz, Fext), wp.dot(jf, Fext) + wp.dot(e0, tau), wp.dot(jt, Fext) + wp.dot(e1, tau))
        Qs[c] = wp.dot(ez, Fext) - ssp
        if c == 0:
            cpl0 = cpl
        elif c == 1:
            cpl1 = cpl
        elif c == 2:
            cpl2 = cpl
        else:
            cpl3 = cpl
    # eliminate the wheel block (diagonal mu): A' = A - sum c c^T / mu
    A = A - (wp.outer(cpl0, cpl0) + wp.outer(cpl1, cpl1) + wp.outer(cpl2, cpl2) + wp.outer(cpl3, cpl3)) / mu
    rhs = Qb - (cpl0 * Qs[0] + cpl1 * Qs[1] + cpl2 * Qs[2] + cpl3 * Qs[3]) / mu
    qdd = wp.inverse(A) * rhs
    sdd = wp.vec4((Qs[0] - wp.dot(cpl0, qdd)) / mu, (Qs[1] - wp.dot(cpl1, qdd)) / mu,
                  (Qs[2] - wp.dot(cpl2, qdd)) / mu, (Qs[3] - wp.dot(cpl3, qdd)) / mu)
    # semi-implicit Euler
    qd = qd + qdd * dt
    q = q + qd * dt
    sd = sd + sdd * dt
    s = s + sd * dt
    st.q[i] = q
    st.qd[i] = qd
    st.s[i] = s
    st.sd[i] = sd
    step = step + 1
    st.step[i] = step
    # IMU from the new state
    p2, R2, psi2, wz2 = pose_of(fl, st, i, dt, step)
    cf2 = wp.cos(q[1])
    sf2 = wp.sin(q[1])
    e1n = wp.vec3(0.0, cf2, -sf2)
    e2n = wp.vec3(-wp.sin(q[2]), sf2 * wp.cos(q[2]), cf2 * wp.cos(q[2]))
    omega2 = e0 * qd[1] + e1n * qd[2] + e2n * wz2
    vcg2 = wp.vec3(wp.cos(psi2) * v, wp.sin(psi2) * v, qd[0])
    r_imu = wp.vec3(fl.params[pi, PIMUX], fl.params[pi, PIMUY], fl.params[pi, PIMUZ])
    vimu = imu_velocity(vcg2, R2, omega2, r_imu)
    acc = (vimu - st.vimu[i]) / dt + wp.vec3(0.0, 0.0, GRAV)
    st.vimu[i] = vimu
    st.acc_sum[i] = st.acc_sum[i] + wp.transpose(R2) * acc
    st.gyro_sum[i] = st.gyro_sum[i] + omega2
    if any_lost != 0:
        st.lost[i] = st.lost[i] + 1
        if st.lost[i] > cfg.lost_limit:
            st.dead[i] = 1
    else:
        st.lost[i] = 0
    if step % cfg.imu_every == 0:
        k = step / cfg.imu_every - 1
        n = float(cfg.imu_every)
        out.acc[i, k] = st.acc_sum[i] / n
        out.gyro[i, k] = st.gyro_sum[i] / n
        st.acc_sum[i] = wp.vec3()
        st.gyro_sum[i] = wp.vec3()
        out.pose[i, k] = q
        for c in range(4):
            b = corner_base(c)
            wc = p2 + R2 * wp.vec3(fl.params[pi, b + 0], fl.params[pi, b + 1], -fl.params[pi, b + 2] + s[c])
            wheel_z[c] = wc[2]
        out.wheel_z[i, k] = wheel_z
        out.tire_f[i, k] = tire_tot
        out.susp[i, k] = s - wp.vec4(fl.params[pi, PC0 + 7], fl.params[pi, PC0 + PCSTRIDE + 7],
                                     fl.params[pi, PC0 + 2 * PCSTRIDE + 7], fl.params[pi, PC0 + 3 * PCSTRIDE + 7])


@kernel
def step_kernel(fl: Fleet, st: State, cfg: Config, out: Output, slices: wp.array2d(dtype=wp.vec4)):
    i = wp.tid()
    if st.dead[i] != 0 or st.step[i] >= fl.nsteps[i]:
        return
    advance_full(fl, st, cfg, out, i, slices)


@kernel
def fused_kernel(mesh: wp.uint64, fl: Fleet, st: State, cfg: Config, out: Output,
                 slices: wp.array2d(dtype=wp.vec4), nsub: int):
    """CPU path: one thread integrates its vehicle ``nsub`` steps, casting its rays inline."""
    i = wp.tid()
    for _k in range(nsub):
        if st.dead[i] != 0 or st.step[i] >= fl.nsteps[i]:
            return
        p, R, psi, wz = pose_of(fl, st, i, cfg.dt, st.step[i])
        omega, v_cg = body_rates(fl, st, i, psi, wz)
        for j in range(4 * cfg.nl):
            slices[i, j] = slice_contact(mesh, fl, st, cfg, i, j, p, R, omega, v_cg)
        advance_full(fl, st, cfg, out, i, slices)


@kernel
def init_full_kernel(mesh: wp.uint64, fl: Fleet, st: State, cfg: Config, ztop: float):
    """Static pose over the road: heave/roll/pitch from the road heights under the 4 wheels,
    springs at their static compression, no vertical motion."""
    i = wp.tid()
    pi = fl.pidx[i]
    v = fl.speed[i]
    xy, psi, dpsi = path_eval(fl, i, fl.s0[i])
    R0 = euler_rot(0.0, 0.0, psi)
    h = wp.vec4()
    ok = int(1)
    for c in range(4):
        b = corner_base(c)
        w = R0 * wp.vec3(fl.params[pi, b + 0], fl.params[pi, b + 1], 0.0)
        hq = wp.mesh_query_ray(mesh, wp.vec3(xy[0] + w[0], xy[1] + w[1], ztop), wp.vec3(0.0, 0.0, -1.0), 1.0e6)
        if hq.result:
            h[c] = ztop - hq.t
        else:
            ok = 0
    xf = fl.params[pi, PC0 + 0]
    xr = fl.params[pi, PC0 + 2 * PCSTRIDE + 0]
    wb = xf - xr
    hf = 0.5 * (h[0] + h[1])
    hr = 0.5 * (h[2] + h[3])
    tf = fl.params[pi, PC0 + 1] - fl.params[pi, PC0 + PCSTRIDE + 1]
    tr = fl.params[pi, PC0 + 2 * PCSTRIDE + 1] - fl.params[pi, PC0 + 3 * PCSTRIDE + 1]
    hcg = hr + (hf - hr) * (-xr) / wb
    theta = -wp.atan((hf - hr) / wb)
    phi = wp.atan(0.5 * ((h[0] - h[1]) / tf + (h[2] - h[3]) / tr))
    q = wp.vec3(hcg + fl.params[pi, PCGH], phi, theta)
    st.q[i] = q
    st.qd[i] = wp.vec3()
    st.s[i] = wp.vec4(fl.params[pi, PC0 + 7], fl.params[pi, PC0 + PCSTRIDE + 7],
                      fl.params[pi, PC0 + 2 * PCSTRIDE + 7], fl.params[pi, PC0 + 3 * PCSTRIDE + 7])
    st.sd[i] = wp.vec4()
    st.step[i] = 0
    st.lost[i] = 0
    st.dead[i] = 1 - ok
    R = euler_rot(phi, theta, psi)
    e2 = wp.vec3(-wp.sin(theta), wp.sin(phi) * wp.cos(theta), wp.cos(phi) * wp.cos(theta))
    omega = e2 * (dpsi * v)
    r_imu = wp.vec3(fl.params[pi, PIMUX], fl.params[pi, PIMUY], fl.params[pi, PIMUZ])
    st.vimu[i] = imu_velocity(wp.vec3(wp.cos(psi) * v, wp.sin(psi) * v, 0.0), R, omega, r_imu)
    st.acc_sum[i] = wp.vec3()
    st.gyro_sum[i] = wp.vec3()


@kernel
def set_state_kernel(st: State, q: wp.array(dtype=wp.vec3), qd: wp.array(dtype=wp.vec3),
                     s: wp.array(dtype=wp.vec4), sd: wp.array(dtype=wp.vec4), mask: wp.array(dtype=wp.int32)):
    """Override the initial state of vehicles whose mask is 1 (validation tests)."""
    i = wp.tid()
    if mask[i] == 0:
        return
    st.q[i] = q[i]
    st.qd[i] = qd[i]
    st.s[i] = s[i]
    st.sd[i] = sd[i]


@kernel
def fix_vimu_kernel(fl: Fleet, st: State, cfg: Config):
    """Recompute the IMU reference velocity after a state override."""
    i = wp.tid()
    pi = fl.pidx[i]
    p, R, psi, wz = pose_of(fl, st, i, cfg.dt, st.step[i])
    q = st.q[i]
    qd = st.qd[i]
    cf = wp.cos(q[1])
    sf = wp.sin(q[1])
    e1 = wp.vec3(0.0, cf, -sf)
    e2 = wp.vec3(-wp.sin(q[2]), sf * wp.cos(q[2]), cf * wp.cos(q[2]))
    omega = wp.vec3(1.0, 0.0, 0.0) * qd[1] + e1 * qd[2] + e2 * wz
    v = fl.speed[i]
    r_imu = wp.vec3(fl.params[pi, PIMUX], fl.params[pi, PIMUY], fl.params[pi, PIMUZ])
    st.vimu[i] = imu_velocity(wp.vec3(wp.cos(psi) * v, wp.sin(psi) * v, qd[0]), R, omega, r_imu)


# ----------------------------------------------------------------------------- quarter car
@kernel
def quarter_kernel(mesh: wp.uint64, fl: Fleet, st: State, cfg: Config, out: Output, nsub: int):
    i = wp.tid()
    pi = fl.pidx[i]
    ms = fl.params[pi, 0]
    mu = fl.params[pi, 1]
    ks = fl.params[pi, 2]
    cs = fl.params[pi, 3]
    kt = fl.params[pi, 4]
    ctire = fl.params[pi, 5]
    radius = fl.params[pi, 6]
    efree = fl.params[pi, 7]
    sstat = fl.params[pi, 8]
    dt = cfg.dt
    down = wp.vec3(0.0, 0.0, -1.0)
    for _k in range(nsub):
        if st.dead[i] != 0 or st.step[i] >= fl.nsteps[i]:
            return
        step = st.step[i]
        xy, psi, dpsi = path_eval(fl, i, fl.s0[i] + fl.speed[i] * float(step) * dt)
        q = st.q[i]
        qd = st.qd[i]
        t = cast(mesh, wp.vec3(xy[0], xy[1], q[1]), down, radius)
        pen = radius - t
        ft = float(0.0)
        if pen > 0.0:
            ft = wp.max(kt * pen - ctire * qd[1], 0.0)
        comp = efree - (q[0] - q[1])
        fs = ks * comp + cs * (qd[1] - qd[0])
        zdd_s = fs / ms - GRAV
        zdd_u = (ft - fs) / mu - GRAV
        qd = wp.vec3(qd[0] + zdd_s * dt, qd[1] + zdd_u * dt, 0.0)
        q = wp.vec3(q[0] + qd[0] * dt, q[1] + qd[1] * dt, 0.0)
        st.q[i] = q
        st.qd[i] = qd
        step = step + 1
        st.step[i] = step
        vz = wp.vec3(0.0, 0.0, qd[0])
        st.acc_sum[i] = st.acc_sum[i] + (vz - st.vimu[i]) / dt + wp.vec3(0.0, 0.0, GRAV)
        st.vimu[i] = vz
        if ft <= 0.0:
            st.lost[i] = st.lost[i] + 1
            if st.lost[i] > cfg.lost_limit:
                st.dead[i] = 1
        else:
            st.lost[i] = 0
        if step % cfg.imu_every == 0:
            k = step / cfg.imu_every - 1
            out.acc[i, k] = st.acc_sum[i] / float(cfg.imu_every)
            out.gyro[i, k] = wp.vec3()
            st.acc_sum[i] = wp.vec3()
            out.pose[i, k] = wp.vec3(q[0], 0.0, 0.0)
            out.wheel_z[i, k] = wp.vec4(q[1], 0.0, 0.0, 0.0)
            out.tire_f[i, k] = wp.vec4(ft, 0.0, 0.0, 0.0)
            out.susp[i, k] = wp.vec4(comp - sstat, 0.0, 0.0, 0.0)


@kernel
def init_quarter_kernel(mesh: wp.uint64, fl: Fleet, st: State, ztop: float):
    i = wp.tid()
    pi = fl.pidx[i]
    xy, psi, dpsi = path_eval(fl, i, fl.s0[i])
    hq = wp.mesh_query_ray(mesh, wp.vec3(xy[0], xy[1], ztop), wp.vec3(0.0, 0.0, -1.0), 1.0e6)
    h = float(0.0)
    st.dead[i] = 1
    if hq.result:
        h = ztop - hq.t
        st.dead[i] = 0
    ms = fl.params[pi, 0]
    mu = fl.params[pi, 1]
    kt = fl.params[pi, 4]
    zu = h + fl.params[pi, 6] - (ms + mu) * GRAV / kt
    st.q[i] = wp.vec3(zu + fl.params[pi, 7] - fl.params[pi, 8], zu, 0.0)
    st.qd[i] = wp.vec3()
    st.step[i] = 0
    st.lost[i] = 0
    st.vimu[i] = wp.vec3()
    st.acc_sum[i] = wp.vec3()


# ----------------------------------------------------------------------------- host side
def resample_path(polyline: np.ndarray, ds: float = 0.5, heading_window_m: float = 2.0):
    """Uniform-arclength resampling of a polyline, with a smoothed, unwrapped heading.

    A straight 2-point path stays 2 points (exact). Returns (xy (K,2), psi (K,), ds)."""
    pts = np.asarray(polyline, dtype=np.float64).reshape(-1, 2)
    seg = np.diff(pts, axis=0)
    keep = np.concatenate([[True], np.linalg.norm(seg, axis=1) > 1e-9])
    pts = pts[keep]
    if len(pts) < 2:
        raise ValueError("path needs at least two distinct points")
    seg = np.diff(pts, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    if len(pts) == 2:
        psi = np.arctan2(seg[0, 1], seg[0, 0])
        return pts.copy(), np.array([psi, psi]), float(cum[-1])
    n = max(2, int(math.ceil(cum[-1] / ds)) + 1)
    s = np.linspace(0.0, cum[-1], n)
    xy = np.column_stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])])
    step = s[1] - s[0]
    half = max(1, int(round(heading_window_m / 2 / step)))
    lo = np.clip(np.arange(n) - half, 0, n - 1)
    hi = np.clip(np.arange(n) + half, 0, n - 1)
    d = xy[hi] - xy[lo]
    psi = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return xy, psi, float(step)


def path_at(xy: np.ndarray, psi: np.ndarray, ds: float, s: np.ndarray) -> np.ndarray:
    """(x, y, yaw) at arclengths ``s`` exactly as the kernels evaluate a resampled path
    (linear inside, straight extrapolation beyond the ends)."""
    u = np.asarray(s, dtype=np.float64) / ds
    k = np.clip(np.floor(u).astype(np.int64), 0, len(xy) - 2)
    f = (u - k)[:, None]
    p = xy[k] + (xy[k + 1] - xy[k]) * f
    fc = np.clip(f[:, 0], 0.0, 1.0)
    return np.column_stack([p, psi[k] + (psi[k + 1] - psi[k]) * fc])


def preload(device, launches) -> float:
    """Compile (or read from warp's kernel cache) the ``(kernel, block_dim)`` variants a run is
    about to launch, all at once on threads (NVRTC runs outside the GIL), before any of them is
    captured into a CUDA graph; returns the seconds it took (about 0 when all were loaded)."""
    t0 = time.perf_counter()
    todo = [(k.module, bd) for k, bd in launches if (device.context, bd) not in k.module.execs]
    if len(todo) > 1:
        with ThreadPoolExecutor(max_workers=len(todo)) as pool:
            for f in [pool.submit(m.load, device, bd) for m, bd in todo]:
                f.result()
    elif todo:
        todo[0][0].load(device, todo[0][1])
    return time.perf_counter() - t0


class VehicleSim:
    """Batched simulator over one static road mesh (numpy in, numpy out).

    ``vehicles``: list of dicts with ``params`` (a plain vehicle dict, see ``pack_vehicle``),
    ``path`` ((K,2) world XY polyline the CG follows; lateral offsets already applied),
    ``s0`` (arclength of the CG along the path at t = 0), ``speed`` (m/s) and ``duration`` (s).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, device: str = "cpu",
                 bvh_constructor: str | None = "sah") -> None:
        quiet()
        wp.init()
        self.device = wp.get_device(device)
        v = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
        f = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1)
        if len(f) == 0:
            raise ValueError("road mesh has no triangles")
        self.ztop = float(v[:, 2].max()) + 5.0
        self.points = wp.array(v, dtype=wp.vec3, device=self.device)
        self.indices = wp.array(f, dtype=wp.int32, device=self.device)
        t0 = time.perf_counter()
        self.mesh = wp.Mesh(points=self.points, indices=self.indices, bvh_constructor=bvh_constructor)
        wp.synchronize_device(self.device)
        self.bvh_s = time.perf_counter() - t0

    def run(self, vehicles: list[dict], dt: float = 1e-3, imu_rate_hz: float = 500.0, tire_slices: int = 3,
            tire_arc_samples: int = 7, tire_arc_deg: float = 45.0, tire_refine: int = 2, lost_after_s: float = 1.0,
            steps_per_launch: int | None = None, graph_steps: int = 100, initial_state: dict | None = None,
            split: bool | None = None, block_dims: tuple[int, int] = (128, 32)) -> dict:
        """Simulate; ``split`` (default: on CUDA) resolves the tire contacts in their own launch
        (one thread per tire slice) before each integration launch (one thread per vehicle);
        otherwise each thread resolves its vehicle's contacts inline and integrates
        ``steps_per_launch`` steps per launch."""
        n = len(vehicles)
        if n == 0:
            raise ValueError("no vehicles")
        modes = {veh["params"].get("mode", "full") for veh in vehicles}
        if len(modes) != 1:
            raise ValueError("all vehicles of one run must share a mode (full or quarter)")
        mode = modes.pop()
        imu_every = max(1, int(round(1.0 / (imu_rate_hz * dt))))
        dev = self.device
        # parameter table (unique dicts)
        rows, pidx, seen = [], [], {}
        for veh in vehicles:
            key = id(veh["params"])
            if key not in seen:
                seen[key] = len(rows)
                rows.append(pack_vehicle(veh["params"]))
            pidx.append(seen[key])
        xs, psis, offs, ns, dss = [], [], [], [], []
        total = 0
        for veh in vehicles:
            xy, psi, ds = resample_path(veh["path"])
            xs.append(xy)
            psis.append(psi)
            offs.append(total)
            ns.append(len(xy))
            dss.append(ds)
            total += len(xy)
        nsteps = np.array([int(round(veh["duration"] / dt)) for veh in vehicles], dtype=np.int32)
        nsteps = (nsteps // imu_every) * imu_every
        T = int(nsteps.max() // imu_every)
        fl = Fleet()
        fl.params = wp.array(np.array(rows), dtype=wp.float32, device=dev)
        fl.pidx = wp.array(np.array(pidx, dtype=np.int32), dtype=wp.int32, device=dev)
        fl.path_xy = wp.array(np.concatenate(xs).astype(np.float32), dtype=wp.vec2, device=dev)
        fl.path_psi = wp.array(np.concatenate(psis).astype(np.float32), dtype=wp.float32, device=dev)
        fl.path_off = wp.array(np.array(offs, dtype=np.int32), dtype=wp.int32, device=dev)
        fl.path_n = wp.array(np.array(ns, dtype=np.int32), dtype=wp.int32, device=dev)
        fl.path_ds = wp.array(np.array(dss, dtype=np.float32), dtype=wp.float32, device=dev)
        fl.s0 = wp.array(np.array([veh["s0"] for veh in vehicles], dtype=np.float32), dtype=wp.float32, device=dev)
        fl.speed = wp.array(np.array([veh["speed"] for veh in vehicles], dtype=np.float32), dtype=wp.float32,
                            device=dev)
        fl.nsteps = wp.array(nsteps, dtype=wp.int32, device=dev)
        st = State()
        st.q = wp.zeros(n, dtype=wp.vec3, device=dev)
        st.qd = wp.zeros(n, dtype=wp.vec3, device=dev)
        st.s = wp.zeros(n, dtype=wp.vec4, device=dev)
        st.sd = wp.zeros(n, dtype=wp.vec4, device=dev)
        st.step = wp.zeros(n, dtype=wp.int32, device=dev)
        st.vimu = wp.zeros(n, dtype=wp.vec3, device=dev)
        st.acc_sum = wp.zeros(n, dtype=wp.vec3, device=dev)
        st.gyro_sum = wp.zeros(n, dtype=wp.vec3, device=dev)
        st.lost = wp.zeros(n, dtype=wp.int32, device=dev)
        st.dead = wp.zeros(n, dtype=wp.int32, device=dev)
        out = Output()
        nan3 = np.full((n, T, 3), np.nan, dtype=np.float32)
        nan4 = np.full((n, T, 4), np.nan, dtype=np.float32)
        out.acc = wp.array(nan3, dtype=wp.vec3, device=dev)
        out.gyro = wp.array(nan3, dtype=wp.vec3, device=dev)
        out.pose = wp.array(nan3, dtype=wp.vec3, device=dev)
        out.wheel_z = wp.array(nan4, dtype=wp.vec4, device=dev)
        out.tire_f = wp.array(nan4, dtype=wp.vec4, device=dev)
        out.susp = wp.array(nan4, dtype=wp.vec4, device=dev)
        cfg = Config()
        cfg.dt = dt
        cfg.imu_every = imu_every
        cfg.nl = max(1, int(tire_slices))
        cfg.na = max(1, int(tire_arc_samples))
        cfg.arc = math.radians(tire_arc_deg)
        cfg.refine = max(0, int(tire_refine))
        cfg.lost_limit = int(round(lost_after_s / dt))
        n_slices = 4 * cfg.nl
        slices = wp.zeros((n, n_slices if mode == "full" else 1), dtype=wp.vec4, device=dev)
        use_split = mode == "full" and (dev.is_cuda if split is None else split)
        compile_s = 0.0
        if dev.is_cuda and use_split:
            compile_s = preload(dev, [(init_full_kernel, init_full_kernel.module.options["block_dim"]),
                                      (contact_kernel, block_dims[0]), (step_kernel, block_dims[1])])
        t0 = time.perf_counter()
        if mode == "full":
            wp.launch(init_full_kernel, dim=n, inputs=[self.mesh.id, fl, st, cfg, self.ztop], device=dev)
        else:
            wp.launch(init_quarter_kernel, dim=n, inputs=[self.mesh.id, fl, st, self.ztop], device=dev)
        if initial_state is not None:
            mask = np.zeros(n, dtype=np.int32)
            q0, qd0 = st.q.numpy(), st.qd.numpy()
            s0_, sd0 = st.s.numpy(), st.sd.numpy()
            for idx, values in initial_state.items():
                mask[idx] = 1
                q0[idx] = values.get("q", q0[idx])
                qd0[idx] = values.get("qd", qd0[idx])
                s0_[idx] = values.get("s", s0_[idx])
                sd0[idx] = values.get("sd", sd0[idx])
            wp.launch(set_state_kernel, dim=n, inputs=[st, wp.array(q0, dtype=wp.vec3, device=dev),
                                                       wp.array(qd0, dtype=wp.vec3, device=dev),
                                                       wp.array(s0_, dtype=wp.vec4, device=dev),
                                                       wp.array(sd0, dtype=wp.vec4, device=dev),
                                                       wp.array(mask, dtype=wp.int32, device=dev)], device=dev)
            if mode == "full":
                wp.launch(fix_vimu_kernel, dim=n, inputs=[fl, st, cfg], device=dev)
            else:
                st.vimu = wp.array(np.column_stack([np.zeros((n, 2)), st.qd.numpy()[:, :1]]).astype(np.float32),
                                   dtype=wp.vec3, device=dev)
        max_steps = int(nsteps.max())
        if mode == "quarter":
            sub = steps_per_launch or 1000
            for _ in range((max_steps + sub - 1) // sub):
                wp.launch(quarter_kernel, dim=n, inputs=[self.mesh.id, fl, st, cfg, out, sub], device=dev)
        elif use_split:
            def one_step():
                wp.launch(contact_kernel, dim=(n, n_slices), inputs=[self.mesh.id, fl, st, cfg, slices], device=dev,
                          block_dim=block_dims[0])
                # small blocks: a few thousand vehicle threads must still reach every SM
                wp.launch(step_kernel, dim=n, inputs=[fl, st, cfg, out, slices], device=dev, block_dim=block_dims[1])
            chunk = max(1, int(graph_steps))
            done = 0
            graph = None
            while done < max_steps:
                if dev.is_cuda and max_steps - done >= chunk:
                    if graph is None:
                        with wp.ScopedCapture(device=dev) as cap:
                            for _ in range(chunk):
                                one_step()
                        graph = cap.graph
                    wp.capture_launch(graph)
                    done += chunk
                else:
                    one_step()
                    done += 1
        else:
            sub = steps_per_launch or imu_every * 25
            for _ in range((max_steps + sub - 1) // sub):
                wp.launch(fused_kernel, dim=n, inputs=[self.mesh.id, fl, st, cfg, out, slices, sub], device=dev)
        wp.synchronize_device(dev)
        wall = time.perf_counter() - t0
        acc = out.acc.numpy().astype(np.float64)
        res = {"t": (np.arange(T) + 1) * imu_every * dt, "acc": acc, "gyro": out.gyro.numpy().astype(np.float64),
               "pose3": out.pose.numpy().astype(np.float64), "wheel_z": out.wheel_z.numpy().astype(np.float64),
               "tire_f": out.tire_f.numpy().astype(np.float64), "susp": out.susp.numpy().astype(np.float64),
               "valid": (nsteps // imu_every).astype(np.int64), "dead": st.dead.numpy().astype(bool),
               "steps": st.step.numpy().astype(np.int64), "wall_s": wall, "bvh_s": self.bvh_s,
               "sim_s": float((nsteps * dt).sum()), "compile_s": compile_s, "imu_dt": imu_every * dt, "dt": dt,
               "mode": mode}
        # x, y, yaw from the paths (they are prescribed)
        xyz = np.full((n, T, 3), np.nan)
        for i, veh in enumerate(vehicles):
            tt = res["t"][: res["valid"][i]]
            xyz[i, : len(tt)] = path_at(xs[i], psis[i], dss[i], veh["s0"] + veh["speed"] * tt)
        p3 = res.pop("pose3")
        res["pose"] = np.concatenate([xyz[..., :2], p3, xyz[..., 2:]], axis=-1)  # x y z roll pitch yaw
        for key in ("acc", "gyro", "pose", "wheel_z", "tire_f", "susp"):
            arr = res[key]
            for i in range(n):
                if res["dead"][i]:
                    last = int(res["steps"][i] // imu_every)
                    arr[i, last:] = np.nan
        return res
