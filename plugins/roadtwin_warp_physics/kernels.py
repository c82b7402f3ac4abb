"""Tire-level vehicle dynamics on warp: N vehicles per launch over one road triangle mesh.

numpy + warp + roadtwin's path resampling (the one every backend drives along). The roadtwin
plugin (``__init__.py``) adapts roadtwin's types to :class:`VehicleSim`.

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

from roadtwin_core.vehicle import resample_path, resampled_path_at
from roadtwin_core.warp_runtime import warp_device

GRAVITY = 9.81

# Packed parameter row of a full vehicle (float32): body and tire fields, then 4 corners
# (FL, FR, RL, RR) of CORNER_FIELDS each; the kernels read every field by these names.
MB, IXX, IYY, IZZ, MU, RADIUS, WIDTH, KT, CT, KSTOP, CSTOP, IMUX, IMUY, IMUZ, CGH = (wp.constant(k) for k in range(15))
CORNER0, CORNER_FIELDS = wp.constant(16), wp.constant(8)
# a corner's fields, relative to its base (corner_base)
CX, CY, CEFREE, CKS, CCS, CSMIN, CSMAX, CSSTAT = (wp.constant(k) for k in range(8))
NP = CORNER0 + 4 * CORNER_FIELDS
# Packed parameter row of a quarter car.
QMS, QMU, QKS, QCS, QKT, QCT, QR, QEFREE, QSSTAT = (wp.constant(k) for k in range(9))
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


def pack_vehicle(p: dict) -> np.ndarray:
    """Plain vehicle dict (``VehicleParams.to_plain()``) -> packed float row."""
    row = np.zeros(NP, dtype=np.float64)
    if p.get("mode", "full") == "quarter":
        row[[QMS, QMU, QKS, QCS, QKT, QCT, QR, QEFREE, QSSTAT]] = [
            p["m_s"], p["m_u"], p["ks"], p["cs"], p["kt"], p["ct"], p["radius"], p["e_free"], p["s_static"]]
        return row
    row[[MB, IXX, IYY, IZZ, MU, RADIUS, WIDTH, KT, CT, KSTOP, CSTOP]] = [
        p["m_b"], p["ixx"], p["iyy"], p["izz"], p["m_u"], p["radius"], p["width"], p["kt"], p["ct"],
        p["k_stop"], p["c_stop"]]
    row[[IMUX, IMUY, IMUZ]] = p["imu"]
    row[CGH] = p["cg_height"]
    for i, c in enumerate(p["corners"]):
        b = CORNER0 + i * CORNER_FIELDS
        row[[b + CX, b + CY, b + CEFREE, b + CKS, b + CCS, b + CSMIN, b + CSMAX, b + CSSTAT]] = [
            c["x"], c["y"], c["e_free"], c["ks"], c["cs"], c["s_min"], c["s_max"], c["s_static"]]
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
    return CORNER0 + c * CORNER_FIELDS


@wp.func
def wheel_mount(fl: Fleet, pi: int, c: int, compression: float):
    """Wheel c's centre in the body frame at a suspension compression."""
    b = corner_base(c)
    return wp.vec3(fl.params[pi, b + CX], fl.params[pi, b + CY], -fl.params[pi, b + CEFREE] + compression)


@wp.func
def imu_mount(fl: Fleet, pi: int):
    """The IMU's position in the body frame."""
    return wp.vec3(fl.params[pi, IMUX], fl.params[pi, IMUY], fl.params[pi, IMUZ])


@wp.func
def static_compressions(fl: Fleet, pi: int):
    """The four suspensions' static compressions."""
    return wp.vec4(fl.params[pi, corner_base(0) + CSSTAT], fl.params[pi, corner_base(1) + CSSTAT],
                   fl.params[pi, corner_base(2) + CSSTAT], fl.params[pi, corner_base(3) + CSSTAT])


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
    radius = fl.params[pi, RADIUS]
    yoff = fl.params[pi, WIDTH] * ((float(sl) + 0.5) / float(nl) - 0.5)
    sc = st.s[i]
    r = wheel_mount(fl, pi, c, sc[c])
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
        f = wp.max((fl.params[pi, KT] * best + fl.params[pi, CT] * rate) / float(nl), 0.0)
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
def tire_load(slices: wp.array2d(dtype=wp.vec4), i: int, c: int, nl: int, width: float):
    """Wheel c's tire from its slices' radial forces (contact stage): total force (body frame),
    moment about the wheel centre (body frame) and summed magnitude."""
    Fw = wp.vec3()
    tau = wp.vec3()
    ftot = float(0.0)
    for sl in range(nl):
        fs4 = slices[i, c * nl + sl]
        Fs = wp.vec3(fs4[0], fs4[1], fs4[2])
        rs = wp.vec3(0.0, width * ((float(sl) + 0.5) / float(nl) - 0.5), 0.0)
        Fw = Fw + Fs
        tau = tau + wp.cross(rs, Fs)
        ftot = ftot + fs4[3]
    return Fw, tau, ftot


@wp.func
def body_terms(fl: Fleet, pi: int, e0: wp.vec3, e1: wp.vec3, omega: wp.vec3, alpha0: wp.vec3):
    """Body block of the generalised mass matrix and forces (coordinates z, phi, theta)."""
    mb = fl.params[pi, MB]
    inertia = wp.vec3(fl.params[pi, IXX], fl.params[pi, IYY], fl.params[pi, IZZ])
    Iw = wp.cw_mul(inertia, omega)
    bias = wp.cw_mul(inertia, alpha0) + wp.cross(omega, Iw)
    Ie1 = wp.cw_mul(inertia, e1)
    A = wp.mat33(mb, 0.0, 0.0,
                 0.0, inertia[0], wp.dot(e0, Ie1),
                 0.0, wp.dot(e0, Ie1), wp.dot(e1, Ie1))
    Qb = wp.vec3(-mb * GRAV, -wp.dot(e0, bias), -wp.dot(e1, bias))
    return A, Qb


@wp.func
def corner_terms(fl: Fleet, pi: int, c: int, s: wp.vec4, sd: wp.vec4, Fw: wp.vec3, tau: wp.vec3, e0: wp.vec3,
                 e1: wp.vec3, e2: wp.vec3, omega: wp.vec3, alpha0: wp.vec3, a_h: wp.vec3):
    """Wheel c (a point mass sliding along the body z axis): its part of the body block of the
    mass matrix, its coupling column, its generalised forces on (z, phi, theta) and on its
    suspension coordinate."""
    mu = fl.params[pi, MU]
    b = corner_base(c)
    ez = wp.vec3(0.0, 0.0, 1.0)
    r = wheel_mount(fl, pi, c, s[c])
    jz = e2
    jf = wp.cross(e0, r)
    jt = wp.cross(e1, r)
    # body-frame Jacobian columns
    dA = mu * wp.mat33(wp.dot(jz, jz), wp.dot(jz, jf), wp.dot(jz, jt),
                       wp.dot(jf, jz), wp.dot(jf, jf), wp.dot(jf, jt),
                       wp.dot(jt, jz), wp.dot(jt, jf), wp.dot(jt, jt))
    cpl = mu * wp.vec3(wp.dot(jz, ez), wp.dot(jf, ez), wp.dot(jt, ez))
    # wheel bias acceleration (body frame)
    a0 = a_h + wp.cross(alpha0, r) + wp.cross(omega, wp.cross(omega, r)) + 2.0 * wp.cross(omega, ez * sd[c])
    Fext = Fw - e2 * (mu * GRAV) - a0 * mu          # external + inertial bias force on the wheel
    ssp = fl.params[pi, b + CKS] * s[c] + fl.params[pi, b + CCS] * sd[c] + stop_force(
        s[c], sd[c], fl.params[pi, b + CSMIN], fl.params[pi, b + CSMAX], fl.params[pi, KSTOP], fl.params[pi, CSTOP])
    dQb = wp.vec3(wp.dot(jz, Fext), wp.dot(jf, Fext) + wp.dot(e0, tau), wp.dot(jt, Fext) + wp.dot(e1, tau))
    return dA, cpl, dQb, wp.dot(ez, Fext) - ssp


@wp.func
def solve_accelerations(A: wp.mat33, Qb: wp.vec3, Qs: wp.vec4, cpl0: wp.vec3, cpl1: wp.vec3, cpl2: wp.vec3,
                        cpl3: wp.vec3, mu: float):
    """Eliminate the (diagonal mu) wheel block, A' = A - sum c c^T / mu, solve the 3x3 body
    system, back-substitute the wheels: (qdd, sdd)."""
    Ar = A - (wp.outer(cpl0, cpl0) + wp.outer(cpl1, cpl1) + wp.outer(cpl2, cpl2) + wp.outer(cpl3, cpl3)) / mu
    rhs = Qb - (cpl0 * Qs[0] + cpl1 * Qs[1] + cpl2 * Qs[2] + cpl3 * Qs[3]) / mu
    qdd = wp.inverse(Ar) * rhs
    sdd = wp.vec4((Qs[0] - wp.dot(cpl0, qdd)) / mu, (Qs[1] - wp.dot(cpl1, qdd)) / mu,
                  (Qs[2] - wp.dot(cpl2, qdd)) / mu, (Qs[3] - wp.dot(cpl3, qdd)) / mu)
    return qdd, sdd


@wp.func
def count_lost(st: State, cfg: Config, i: int, lost: bool):
    """Consecutive steps with a wheel off the road; too many end the vehicle's run."""
    if lost:
        st.lost[i] = st.lost[i] + 1
        if st.lost[i] > cfg.lost_limit:
            st.dead[i] = 1
    else:
        st.lost[i] = 0


@wp.func
def sense(fl: Fleet, st: State, cfg: Config, out: Output, i: int, any_lost: int, tire_tot: wp.vec4):
    """After a step: the IMU (delta-velocity of its point, body frame), the lost-wheel count,
    and at the end of an IMU interval one output sample."""
    pi = fl.pidx[i]
    dt = cfg.dt
    step = st.step[i]
    q = st.q[i]
    qd = st.qd[i]
    s = st.s[i]
    v = fl.speed[i]
    p2, R2, psi2, wz2 = pose_of(fl, st, i, dt, step)
    cf2 = wp.cos(q[1])
    sf2 = wp.sin(q[1])
    e1n = wp.vec3(0.0, cf2, -sf2)
    e2n = wp.vec3(-wp.sin(q[2]), sf2 * wp.cos(q[2]), cf2 * wp.cos(q[2]))
    omega2 = wp.vec3(1.0, 0.0, 0.0) * qd[1] + e1n * qd[2] + e2n * wz2
    vcg2 = wp.vec3(wp.cos(psi2) * v, wp.sin(psi2) * v, qd[0])
    vimu = imu_velocity(vcg2, R2, omega2, imu_mount(fl, pi))
    acc = (vimu - st.vimu[i]) / dt + wp.vec3(0.0, 0.0, GRAV)
    st.vimu[i] = vimu
    st.acc_sum[i] = st.acc_sum[i] + wp.transpose(R2) * acc
    st.gyro_sum[i] = st.gyro_sum[i] + omega2
    count_lost(st, cfg, i, any_lost != 0)
    if step % cfg.imu_every == 0:
        k = step / cfg.imu_every - 1
        n = float(cfg.imu_every)
        out.acc[i, k] = st.acc_sum[i] / n
        out.gyro[i, k] = st.gyro_sum[i] / n
        st.acc_sum[i] = wp.vec3()
        st.gyro_sum[i] = wp.vec3()
        out.pose[i, k] = q
        wheel_z = wp.vec4()
        for c in range(4):
            wc = p2 + R2 * wheel_mount(fl, pi, c, s[c])
            wheel_z[c] = wc[2]
        out.wheel_z[i, k] = wheel_z
        out.tire_f[i, k] = tire_tot
        out.susp[i, k] = s - static_compressions(fl, pi)


@wp.func
def advance_full(fl: Fleet, st: State, cfg: Config, out: Output, i: int, slices: wp.array2d(dtype=wp.vec4)):
    """One step of vehicle i from its tire slices' forces: projected Newton-Euler for the body
    and the four wheels, semi-implicit Euler, then the sensors."""
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
    left = wp.vec3(-wp.sin(psi), wp.cos(psi), 0.0)
    a_h = wp.transpose(R) * (left * (v * wz))    # prescribed (centripetal) CG acceleration, body frame
    A, Qb = body_terms(fl, pi, e0, e1, omega, alpha0)
    Qs = wp.vec4()
    cpl0 = wp.vec3()
    cpl1 = wp.vec3()
    cpl2 = wp.vec3()
    cpl3 = wp.vec3()
    tire_tot = wp.vec4()
    any_lost = int(0)
    for c in range(4):
        Fw, tau, ftot = tire_load(slices, i, c, cfg.nl, fl.params[pi, WIDTH])
        if ftot <= 0.0:
            any_lost = 1
        tire_tot[c] = ftot
        dA, cpl, dQb, qs = corner_terms(fl, pi, c, s, sd, Fw, tau, e0, e1, e2, omega, alpha0, a_h)
        A = A + dA
        Qb = Qb + dQb
        Qs[c] = qs
        if c == 0:
            cpl0 = cpl
        elif c == 1:
            cpl1 = cpl
        elif c == 2:
            cpl2 = cpl
        else:
            cpl3 = cpl
    qdd, sdd = solve_accelerations(A, Qb, Qs, cpl0, cpl1, cpl2, cpl3, fl.params[pi, MU])
    # semi-implicit Euler
    qd = qd + qdd * dt
    q = q + qd * dt
    sd = sd + sdd * dt
    s = s + sd * dt
    st.q[i] = q
    st.qd[i] = qd
    st.s[i] = s
    st.sd[i] = sd
    st.step[i] = step + 1
    sense(fl, st, cfg, out, i, any_lost, tire_tot)


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
        w = R0 * wp.vec3(fl.params[pi, b + CX], fl.params[pi, b + CY], 0.0)
        hq = wp.mesh_query_ray(mesh, wp.vec3(xy[0] + w[0], xy[1] + w[1], ztop), wp.vec3(0.0, 0.0, -1.0), 1.0e6)
        if hq.result:
            h[c] = ztop - hq.t
        else:
            ok = 0
    xf = fl.params[pi, corner_base(0) + CX]
    xr = fl.params[pi, corner_base(2) + CX]
    wb = xf - xr
    hf = 0.5 * (h[0] + h[1])
    hr = 0.5 * (h[2] + h[3])
    tf = fl.params[pi, corner_base(0) + CY] - fl.params[pi, corner_base(1) + CY]
    tr = fl.params[pi, corner_base(2) + CY] - fl.params[pi, corner_base(3) + CY]
    hcg = hr + (hf - hr) * (-xr) / wb
    theta = -wp.atan((hf - hr) / wb)
    phi = wp.atan(0.5 * ((h[0] - h[1]) / tf + (h[2] - h[3]) / tr))
    q = wp.vec3(hcg + fl.params[pi, CGH], phi, theta)
    st.q[i] = q
    st.qd[i] = wp.vec3()
    st.s[i] = static_compressions(fl, pi)
    st.sd[i] = wp.vec4()
    st.step[i] = 0
    st.lost[i] = 0
    st.dead[i] = 1 - ok
    R = euler_rot(phi, theta, psi)
    e2 = wp.vec3(-wp.sin(theta), wp.sin(phi) * wp.cos(theta), wp.cos(phi) * wp.cos(theta))
    omega = e2 * (dpsi * v)
    r_imu = imu_mount(fl, pi)
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
    r_imu = imu_mount(fl, pi)
    st.vimu[i] = imu_velocity(wp.vec3(wp.cos(psi) * v, wp.sin(psi) * v, qd[0]), R, omega, r_imu)


# ----------------------------------------------------------------------------- quarter car
@kernel
def quarter_kernel(mesh: wp.uint64, fl: Fleet, st: State, cfg: Config, out: Output, nsub: int):
    i = wp.tid()
    pi = fl.pidx[i]
    ms = fl.params[pi, QMS]
    mu = fl.params[pi, QMU]
    ks = fl.params[pi, QKS]
    cs = fl.params[pi, QCS]
    kt = fl.params[pi, QKT]
    ctire = fl.params[pi, QCT]
    radius = fl.params[pi, QR]
    efree = fl.params[pi, QEFREE]
    sstat = fl.params[pi, QSSTAT]
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
        count_lost(st, cfg, i, ft <= 0.0)
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
    ms = fl.params[pi, QMS]
    mu = fl.params[pi, QMU]
    kt = fl.params[pi, QKT]
    zu = h + fl.params[pi, QR] - (ms + mu) * GRAV / kt
    st.q[i] = wp.vec3(zu + fl.params[pi, QEFREE] - fl.params[pi, QSSTAT], zu, 0.0)
    st.qd[i] = wp.vec3()
    st.step[i] = 0
    st.lost[i] = 0
    st.vimu[i] = wp.vec3()
    st.acc_sum[i] = wp.vec3()


# ----------------------------------------------------------------------------- host side
def pack_fleet(vehicles: list[dict], dt: float, imu_every: int, dev) -> tuple[Fleet, list, np.ndarray]:
    """The per-vehicle constants on the device: one packed parameter row per distinct parameter
    dict, the resampled paths end to end. Returns (fleet, paths as (xy, psi, ds), steps per
    vehicle in whole IMU intervals)."""
    rows, pidx, seen = [], [], {}
    for veh in vehicles:
        key = id(veh["params"])
        if key not in seen:
            seen[key] = len(rows)
            rows.append(pack_vehicle(veh["params"]))
        pidx.append(seen[key])
    paths = [resample_path(veh["path"]) for veh in vehicles]
    sizes = [len(xy) for xy, _, _ in paths]
    nsteps = np.array([int(round(veh["duration"] / dt)) for veh in vehicles], dtype=np.int32)
    nsteps = (nsteps // imu_every) * imu_every

    def arr(values, np_dtype, wp_dtype):
        return wp.array(np.asarray(values, dtype=np_dtype), dtype=wp_dtype, device=dev)
    fl = Fleet()
    fl.params = arr(np.array(rows), np.float32, wp.float32)
    fl.pidx = arr(pidx, np.int32, wp.int32)
    fl.path_xy = arr(np.concatenate([xy for xy, _, _ in paths]), np.float32, wp.vec2)
    fl.path_psi = arr(np.concatenate([psi for _, psi, _ in paths]), np.float32, wp.float32)
    fl.path_off = arr(np.concatenate([[0], np.cumsum(sizes)[:-1]]), np.int32, wp.int32)
    fl.path_n = arr(sizes, np.int32, wp.int32)
    fl.path_ds = arr([ds for _, _, ds in paths], np.float32, wp.float32)
    fl.s0 = arr([veh["s0"] for veh in vehicles], np.float32, wp.float32)
    fl.speed = arr([veh["speed"] for veh in vehicles], np.float32, wp.float32)
    fl.nsteps = arr(nsteps, np.int32, wp.int32)
    return fl, paths, nsteps


def new_state(n: int, dev) -> State:
    st = State()
    for name, dtype in (("q", wp.vec3), ("qd", wp.vec3), ("s", wp.vec4), ("sd", wp.vec4), ("step", wp.int32),
                        ("vimu", wp.vec3), ("acc_sum", wp.vec3), ("gyro_sum", wp.vec3), ("lost", wp.int32),
                        ("dead", wp.int32)):
        setattr(st, name, wp.zeros(n, dtype=dtype, device=dev))
    return st


OUTPUTS = (("acc", wp.vec3, 3), ("gyro", wp.vec3, 3), ("pose", wp.vec3, 3), ("wheel_z", wp.vec4, 4),
           ("tire_f", wp.vec4, 4), ("susp", wp.vec4, 4))


def new_output(n: int, samples: int, dev) -> Output:
    """Every output sample NaN until written (a vehicle that ends early keeps NaN)."""
    out = Output()
    for name, dtype, width in OUTPUTS:
        setattr(out, name, wp.array(np.full((n, samples, width), np.nan, dtype=np.float32),
                                    dtype=dtype, device=dev))
    return out


def unpack_output(out: Output, st: State, vehicles: list[dict], paths: list, nsteps: np.ndarray, imu_every: int,
                  dt: float) -> dict:
    """Device outputs -> float64 numpy; x, y, yaw from the (prescribed) paths; NaN after a
    vehicle left the road."""
    res = {name: getattr(out, name).numpy().astype(np.float64) for name, _, _ in OUTPUTS}
    n, T = res["acc"].shape[:2]
    t = (np.arange(T) + 1) * imu_every * dt
    valid = (nsteps // imu_every).astype(np.int64)
    dead = st.dead.numpy().astype(bool)
    steps = st.step.numpy().astype(np.int64)
    xyz = np.full((n, T, 3), np.nan)
    for i, (veh, (xy, psi, ds)) in enumerate(zip(vehicles, paths)):
        tt = t[: valid[i]]
        p, yaw, _ = resampled_path_at(xy, psi, ds, veh["s0"] + veh["speed"] * tt)
        xyz[i, : len(tt)] = np.column_stack([p, yaw])
    p3 = res["pose"]
    res["pose"] = np.concatenate([xyz[..., :2], p3, xyz[..., 2:]], axis=-1)  # x y z roll pitch yaw
    for key in ("acc", "gyro", "pose", "wheel_z", "tire_f", "susp"):
        arr = res[key]
        for i in range(n):
            if dead[i]:
                arr[i, int(steps[i] // imu_every):] = np.nan
    res.update({"t": t, "valid": valid, "dead": dead, "steps": steps})
    return res


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
        self.device = warp_device(device)
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
        fl, paths, nsteps = pack_fleet(vehicles, dt, imu_every, dev)
        T = int(nsteps.max() // imu_every)
        st, out = new_state(n, dev), new_output(n, T, dev)
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
        self._start(mode, fl, st, cfg, initial_state)
        max_steps = int(nsteps.max())
        if mode == "quarter":
            sub = steps_per_launch or 1000
            for _ in range((max_steps + sub - 1) // sub):
                wp.launch(quarter_kernel, dim=n, inputs=[self.mesh.id, fl, st, cfg, out, sub], device=dev)
        elif use_split:
            self._steps_split(fl, st, cfg, out, slices, max_steps, graph_steps, block_dims)
        else:
            sub = steps_per_launch or imu_every * 25
            for _ in range((max_steps + sub - 1) // sub):
                wp.launch(fused_kernel, dim=n, inputs=[self.mesh.id, fl, st, cfg, out, slices, sub], device=dev)
        wp.synchronize_device(dev)
        wall = time.perf_counter() - t0
        res = unpack_output(out, st, vehicles, paths, nsteps, imu_every, dt)
        res.update({"wall_s": wall, "bvh_s": self.bvh_s, "sim_s": float((nsteps * dt).sum()), "compile_s": compile_s,
                    "imu_dt": imu_every * dt, "dt": dt, "mode": mode})
        return res

    def _start(self, mode: str, fl: Fleet, st: State, cfg: Config, initial_state: dict | None) -> None:
        """Every vehicle at rest on its springs over the road, then the given initial states."""
        dev = self.device
        n = st.q.shape[0]
        if mode == "full":
            wp.launch(init_full_kernel, dim=n, inputs=[self.mesh.id, fl, st, cfg, self.ztop], device=dev)
        else:
            wp.launch(init_quarter_kernel, dim=n, inputs=[self.mesh.id, fl, st, self.ztop], device=dev)
        if initial_state is None:
            return
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

    def _steps_split(self, fl: Fleet, st: State, cfg: Config, out: Output, slices, max_steps: int, graph_steps: int,
                     block_dims: tuple[int, int]) -> None:
        """Contacts and integration in separate launches; on CUDA chunks of steps are replayed
        as one captured graph."""
        dev = self.device
        n, n_slices = slices.shape

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
