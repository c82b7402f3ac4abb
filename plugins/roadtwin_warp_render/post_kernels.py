"""The camera model and the ego-lane labels as warp kernels: frames finished on the device.

Why: on a GPU the ray casting and shading take well under a millisecond a frame; the CPU's share
(``roadtwin_core.render.randomize.apply_sensor`` and ``roadtwin_core.render.ego_lane``: numpy
noise on half a million values, motion blur, auto-exposure, a k-d tree over the lane) took
~175 ms a frame. Here the same model runs where the G-buffer is, on a batch of frames, and only
8-bit images and labels (with depth and instances) travel to the host.

The same model, step for step (``apply_sensor``'s order): motion blur along each pixel's image
motion while the car moves ``travel`` (taps per pixel, half a pixel apart, 5 to 25; the CPU takes
one count for the frame, a pixel apart: as close to the exposure integral, see the tests) -> optics blur (Gaussian, reflecting border) -> vignetting cos^(4 s) ->
auto-exposure (the scale whose mean displayed luminance on every 4th pixel of every 4th row hits
the target: bracketed by candidate grids, ``AE_ROUNDS`` rounds of ``AE_CANDIDATES``, instead of
40 bisection steps) -> exposure -> Poisson photon noise (``gain``) + Gaussian read noise from
warp's counter-based generator keyed by (frame seed, pixel, channel) -> white balance ->
saturation -> the tone curve and sRGB -> 8 bit. Other random numbers than numpy's: other bytes
than the CPU path (same seed, same device: same bytes). JPEG stays on the host (Pillow).

Ego lane: each road pixel's world point (from the G-buffer ray) projected on every piece of the
lane centreline (exact nearest piece; the CPU takes the two pieces beside the nearest of its
0.25 m samples: the same piece but at rare bends), ego where |lateral| <= half the lane width,
the foot inside the polyline and ahead of the camera along it; the class map's two 256-entry
tables (outside / inside the ego mask) then give the dataset labels.
"""
from __future__ import annotations

import warp as wp

from .raycast import Cam, cam_ray

wp.set_module_options({"enable_backward": False})

AE_CANDIDATES = wp.constant(64)      # exposure scales tried per round (log-spaced)
AE_ROUNDS = 4                        # 64^4: the bracket narrows to ~1e-6 of log(1e8)
AE_CHUNKS = wp.constant(64)          # threads summing one candidate's samples
MAX_BLUR_TAPS = wp.constant(25)


@wp.struct
class Sensor:
    """One frame's camera model (``ImageEffects``, resolved for the device)."""

    travel: wp.vec3            # camera displacement during the exposure, camera axes (motion blur)
    vignetting: float          # exponent scale of cos^4 (0: none)
    target: float              # auto-exposure target luminance (<= 0: fixed exposure)
    exposure: float
    gain: float                # photon noise: variance = gain * signal (0: none)
    read_noise: float
    wb: wp.vec3
    saturation: float
    seed: int                  # noise stream of the frame (from its noise seed)


@wp.func
def reflect(i: int, n: int) -> int:
    """cv2.BORDER_REFLECT (fedcba|abcdef|fedcba) index folding."""
    r = i
    if n == 1:
        r = 0
    else:
        p = ((r % (2 * n)) + 2 * n) % (2 * n)
        r = p
        if p >= n:
            r = 2 * n - 1 - p
    return r


@wp.func
def bilinear_reflect(img: wp.array(dtype=wp.vec3), base: int, w: int, h: int, x: float, y: float) -> wp.vec3:
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = reflect(int(x0), w)
    i1 = reflect(int(x0) + 1, w)
    j0 = reflect(int(y0), h)
    j1 = reflect(int(y0) + 1, h)
    top = img[base + j0 * w + i0] * (1.0 - fx) + img[base + j0 * w + i1] * fx
    bot = img[base + j1 * w + i0] * (1.0 - fx) + img[base + j1 * w + i1] * fx
    return top * (1.0 - fy) + bot * fy


@wp.kernel
def motion_blur_kernel(rgb: wp.array(dtype=wp.vec3), depth: wp.array(dtype=float), cam: Cam, travel: wp.vec3,
                       slot: int, out: wp.array(dtype=wp.vec3)):
    """The shaded frame averaged along each pixel's image motion over the exposure (centred),
    into batch slot ``slot`` of ``out``; a pixel without a hit or with < 0.25 px of motion stays."""
    tid = wp.tid()
    w = cam.width
    h = cam.height
    i = tid % w
    j = tid // w
    z = depth[tid]
    fu = float(0.0)
    fv = float(0.0)
    if z > 0.0:
        x = (float(i) - cam.cx) / cam.fx * z
        y = (float(j) - cam.cy) / cam.fy * z
        z2 = wp.max(z - travel[2], 1.0e-3)
        fu = cam.fx * (x - travel[0]) / z2 + cam.cx - float(i)
        fv = cam.fy * (y - travel[1]) / z2 + cam.cy - float(j)
    longest = wp.max(wp.abs(fu), wp.abs(fv))
    c = rgb[tid]
    if longest >= 0.25:
        taps = wp.clamp(int(wp.ceil(2.0 * longest)) + 1, 5, MAX_BLUR_TAPS)
        c = wp.vec3(0.0, 0.0, 0.0)
        for k in range(taps):
            t = -0.5 + float(k) / float(taps - 1)
            c = c + bilinear_reflect(rgb, 0, w, h, float(i) + t * fu, float(j) + t * fv)
        c = c / float(taps)
    out[slot * w * h + tid] = c


@wp.kernel
def gauss_kernel(src: wp.array(dtype=wp.vec3), weights: wp.array(dtype=float), radius: int, w: int, h: int,
                 horizontal: int, dst: wp.array(dtype=wp.vec3)):
    """One pass of a separable Gaussian (reflecting border) over a batch of frames."""
    tid = wp.tid()
    n = w * h
    base = (tid // n) * n
    p = tid % n
    i = p % w
    j = p // w
    c = wp.vec3(0.0, 0.0, 0.0)
    for k in range(2 * radius + 1):
        if horizontal != 0:
            c = c + src[base + j * w + reflect(i + k - radius, w)] * weights[k]
        else:
            c = c + src[base + reflect(j + k - radius, h) * w + i] * weights[k]
    dst[tid] = c


@wp.func
def vignette(cam: Cam, i: int, j: int, strength: float) -> float:
    v = float(1.0)
    if strength > 0.0:
        xn = (float(i) - cam.cx) / cam.fx
        yn = (float(j) - cam.cy) / cam.fy
        v = wp.pow(1.0 / (1.0 + xn * xn + yn * yn), 2.0 * strength)
    return v


@wp.kernel
def exposure_sums_kernel(lin: wp.array(dtype=wp.vec3), cam: Cam, sensors: wp.array(dtype=Sensor),
                         lo: wp.array(dtype=float), hi: wp.array(dtype=float), sums: wp.array(dtype=float)):
    """For every frame and candidate scale k (log-spaced in [lo, hi]): the displayed luminance
    sum_c w_c (1 - exp(-k c)) over every 4th pixel of every 4th row, in AE_CHUNKS partial sums
    (added in a fixed order by the bracket kernel: no atomics, so the same frame gives the same
    scale to the last bit)."""
    tid = wp.tid()
    chunk = tid % AE_CHUNKS
    cand = (tid // AE_CHUNKS) % AE_CANDIDATES
    b = tid // (AE_CHUNKS * AE_CANDIDATES)
    if sensors[b].target <= 0.0:
        return
    k = wp.exp(lo[b] + (hi[b] - lo[b]) * float(cand) / float(AE_CANDIDATES - 1))
    w = cam.width
    cols = (w + 3) // 4
    n = cols * ((cam.height + 3) // 4)
    base = b * w * cam.height
    s = float(0.0)
    for q in range(chunk, n, AE_CHUNKS):
        i = (q % cols) * 4
        j = (q // cols) * 4
        c = lin[base + j * w + i] * vignette(cam, i, j, sensors[b].vignetting)
        s += 0.2126 * (1.0 - wp.exp(-k * wp.max(c[0], 0.0))) + 0.7152 * (1.0 - wp.exp(-k * wp.max(c[1], 0.0))) \
            + 0.0722 * (1.0 - wp.exp(-k * wp.max(c[2], 0.0)))
    sums[tid] = s


@wp.kernel
def exposure_bracket_kernel(cam: Cam, sensors: wp.array(dtype=Sensor), sums: wp.array(dtype=float),
                            lo: wp.array(dtype=float), hi: wp.array(dtype=float)):
    """Per frame: the bracket [lo, hi] narrowed to the two candidates around the target (the
    displayed mean grows with k). A black frame: k = 1."""
    b = wp.tid()
    if sensors[b].target <= 0.0:
        return
    n = float(((cam.width + 3) // 4) * ((cam.height + 3) // 4))
    goal = sensors[b].target * n
    a = lo[b]
    step = (hi[b] - a) / float(AE_CANDIDATES - 1)
    first = int(AE_CANDIDATES)
    top = float(0.0)
    for c in range(AE_CANDIDATES):
        total = float(0.0)
        for k in range(AE_CHUNKS):
            total += sums[(b * AE_CANDIDATES + c) * AE_CHUNKS + k]
        if first == AE_CANDIDATES and total >= goal:
            first = c
        top = total
    if top <= 0.0:
        lo[b] = 0.0
        hi[b] = 0.0
    elif first == 0:
        hi[b] = a
    elif first < AE_CANDIDATES:
        lo[b] = a + step * float(first - 1)
        hi[b] = a + step * float(first)
    else:
        lo[b] = a + step * float(AE_CANDIDATES - 1)


@wp.func
def srgb8(x: float) -> wp.uint8:
    y = 1.0 - wp.exp(-wp.max(x, 0.0))
    s = float(0.0)
    if y <= 0.0031308:
        s = 12.92 * y
    else:
        s = 1.055 * wp.pow(y, 1.0 / 2.4) - 0.055
    return wp.uint8(int(wp.clamp(wp.round(s * 255.0), 0.0, 255.0)))


@wp.kernel
def sensor_kernel(lin: wp.array(dtype=wp.vec3), cam: Cam, sensors: wp.array(dtype=Sensor),
                  lo: wp.array(dtype=float), hi: wp.array(dtype=float), out: wp.array(dtype=wp.uint8)):
    """Vignetting, exposure (auto and fixed), photon + read noise, white balance, saturation,
    tone curve and sRGB: 8-bit RGB of a batch of frames."""
    tid = wp.tid()
    n = cam.width * cam.height
    b = tid // n
    p = tid % n
    S = sensors[b]
    scale = S.exposure * vignette(cam, p % cam.width, p // cam.width, S.vignetting)
    if S.target > 0.0:
        scale = scale * wp.exp(0.5 * (lo[b] + hi[b]))
    x = lin[tid] * scale
    state = wp.rand_init(S.seed, 3 * p)
    for c in range(3):
        v = wp.max(x[c], 0.0)
        if S.gain > 0.0:
            v = float(wp.poisson(state, v / S.gain)) * S.gain
        if S.read_noise > 0.0:
            v = v + wp.randn(state) * S.read_noise
        x[c] = v
    x = wp.cw_mul(x, S.wb)
    if S.saturation != 1.0:
        y = 0.2126 * x[0] + 0.7152 * x[1] + 0.0722 * x[2]
        x = wp.vec3(y, y, y) + (x - wp.vec3(y, y, y)) * S.saturation
    for c in range(3):
        out[3 * tid + c] = srgb8(x[c])


@wp.kernel
def labels_kernel(cam: Cam, dist: wp.array(dtype=float), face: wp.array(dtype=wp.int32),
                  cls: wp.array(dtype=wp.int32), label_distance: float, background: int,
                  lane: wp.array(dtype=wp.vec2), n_lane: int, half_width: float, s_cam: float,
                  plain: wp.array(dtype=wp.uint8), inside: wp.array(dtype=wp.uint8), use_lut: int,
                  slot: int, out: wp.array(dtype=wp.uint8)):
    """The frame's labels into batch slot ``slot``: the renderer's classes (255 beyond the label
    distance), through the class map's tables with the ego lane when ``use_lut``."""
    tid = wp.tid()
    f = face[tid]
    c = background
    if f >= 0:
        c = cls[tid]
        if dist[tid] > label_distance:
            c = 255
    label = wp.uint8(c)
    if use_lut != 0:
        label = plain[c]
        if n_lane >= 2 and f >= 0 and c != 0 and c != 255:
            d, sc = cam_ray(cam, tid % cam.width, tid // cam.width)
            q = cam.pos + d * dist[tid]
            if is_ego(wp.vec2(q[0], q[1]), lane, n_lane, half_width, s_cam):
                label = inside[c]
    out[slot * cam.width * cam.height + tid] = label


@wp.func
def is_ego(q: wp.vec2, lane: wp.array(dtype=wp.vec2), n_lane: int, half_width: float, s_cam: float) -> bool:
    """Within half a lane width of the centreline's nearest piece, its foot inside the
    polyline, ahead of the camera (arc length >= ``s_cam``)."""
    best = float(1.0e30)
    best_s = float(0.0)
    best_ok = bool(False)
    s0 = float(0.0)
    for j in range(n_lane - 1):
        a = lane[j]
        ab = lane[j + 1] - a
        ll = wp.max(wp.dot(ab, ab), 1.0e-24)
        t_raw = wp.dot(q - a, ab) / ll
        t = wp.clamp(t_raw, 0.0, 1.0)
        e = q - a - ab * t
        d2 = wp.dot(e, e)
        if d2 < best:
            best = d2
            best_s = s0 + t * wp.sqrt(ll)
            best_ok = (t_raw >= 0.0 or j > 0) and (t_raw <= 1.0 or j < n_lane - 2)
        s0 = s0 + wp.sqrt(ll)
    return best_ok and best <= half_width * half_width and best_s >= s_cam


@wp.kernel
def gather_kernel(depth: wp.array(dtype=float), inst: wp.array(dtype=wp.int32), slot: int,
                  depth_out: wp.array(dtype=float), inst_out: wp.array(dtype=wp.int32)):
    """Depth and instances of a frame into batch slot ``slot`` (one copy to the host a batch)."""
    tid = wp.tid()
    k = slot * depth.shape[0] + tid
    depth_out[k] = depth[tid]
    inst_out[k] = inst[tid]
