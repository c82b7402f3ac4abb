"""Ray-cast G-buffer and procedural shading on warp: numpy + warp only.

This file imports nothing but numpy and warp, so ``bench/render.py`` loads it by path on a GPU
machine with no USD (and no roadtwin) installed. Everything is plain arrays:

- the scene is one ``wp.Mesh`` of all triangles (roads and defects) with per-face arrays:
  semantic class id, instance id (0 = not a defect), material id and a tint in [0, 1) (one value
  per road segment, for per-segment variation);
- a camera is a pinhole (fx, fy, cx, cy, width, height) with a camera-to-world rotation whose
  columns are the camera's x (right), y (down), z (forward) axes in world coordinates (OpenCV
  convention) and a centre; pixel (i, j) looks through image point (i, j) (pixel centres at
  integer coordinates, as in OpenCV's projection);
- the G-buffer holds, per pixel: z-depth along the optical axis (0 = no hit), ray length, the
  unit normal in camera coordinates (facing the camera), class, instance and face id (-1);
- shading turns a G-buffer into linear RGB radiance: procedural asphalt / cobblestone / cement
  textures in world XY, defects darker, rougher and wet-looking, a sun with ray-traced shadows,
  a sky gradient by direction, wet-road specular and sky reflection, exponential fog.

World: Z up, metres. Nothing here knows about USD, files or the plugin manager.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

MATERIALS = ("asphalt", "cobblestone", "cement")
MAT_ASPHALT, MAT_COBBLESTONE, MAT_CEMENT = 0, 1, 2


@wp.struct
class Cam:
    fx: float
    fy: float
    cx: float
    cy: float
    rot: wp.mat33      # camera -> world rotation (columns: x right, y down, z forward)
    pos: wp.vec3       # camera centre, world
    width: int
    height: int


@wp.struct
class Light:
    sun_dir: wp.vec3   # unit vector towards the sun
    sun_rgb: wp.vec3   # sun irradiance colour (linear)
    sky_zenith: wp.vec3
    sky_horizon: wp.vec3
    ground_rgb: wp.vec3  # what a ray that misses the town sees below the horizon
    ambient: float     # sky light on an up-facing surface, relative to the sky colour
    fog_density: float  # 1/m, exponential in ray length
    fog_rgb: wp.vec3
    wetness: float     # 0 dry .. 1 soaked (darker albedo, strong specular + sky reflection)
    shadows: int
    seed: int


# --------------------------------------------------------------------------------- helpers
@wp.func
def cam_ray(cam: Cam, i: int, j: int):
    dc = wp.vec3((float(i) - cam.cx) / cam.fx, (float(j) - cam.cy) / cam.fy, 1.0)
    return wp.normalize(cam.rot * dc), wp.length(dc)


@wp.func
def hash01(seed: int, a: int, b: int) -> float:
    """Deterministic value in [0, 1) for an integer lattice cell."""
    s = wp.rand_init(seed, a * 73856093 + b * 19349663)
    return wp.randf(s)


@wp.func
def fade(footprint: float, wavelength: float) -> float:
    """Weight of a texture octave: 1 when a pixel is much smaller than its wavelength, 0 when
    the pixel covers a whole period (a cheap band limit against aliasing)."""
    return wp.clamp(1.5 - 2.0 * footprint / wavelength, 0.0, 1.0)


@wp.func
def sky(d: wp.vec3, L: Light) -> wp.vec3:
    up = wp.max(d[2], 0.0)
    c = L.sky_horizon + (L.sky_zenith - L.sky_horizon) * wp.sqrt(up)
    s = wp.max(wp.dot(d, L.sun_dir), 0.0)
    c = c + L.sun_rgb * (0.08 * wp.pow(s, 8.0) + 4.0 * wp.pow(s, 2000.0))
    if d[2] < 0.0:
        # below the horizon and no town geometry: distant ground fading into the horizon haze
        k = wp.exp(d[2] * 12.0)
        c = L.ground_rgb * (1.0 - k) + L.sky_horizon * k
    if L.fog_density > 0.0:
        c = c * 0.15 + L.fog_rgb * 0.85
    return c


@wp.func
def asphalt(seed: int, x: float, y: float, tint: float, fp: float) -> wp.vec3:
    s1 = wp.rand_init(seed + 11)
    s2 = wp.rand_init(seed + 12)
    s3 = wp.rand_init(seed + 13)
    a = 0.095 + 0.02 * tint
    a = a + 0.020 * wp.noise(s1, wp.vec2(x * 0.7, y * 0.7))
    a = a + 0.018 * wp.noise(s2, wp.vec2(x * 9.0, y * 9.0)) * fade(fp, 0.11)
    a = a + 0.030 * wp.noise(s3, wp.vec2(x * 45.0, y * 45.0)) * fade(fp, 0.022)
    # light aggregate chips: a round stone at a random spot in some 1.5 cm cells
    w = fade(fp, 0.03)
    if w > 0.0:
        gx = x * 66.0
        gy = y * 66.0
        cx = int(wp.floor(gx))
        cy = int(wp.floor(gy))
        st = wp.rand_init(seed + 14, cx * 73856093 + cy * 19349663)
        if wp.randf(st) < 0.06:
            ox = float(cx) + 0.25 + 0.5 * wp.randf(st)
            oy = float(cy) + 0.25 + 0.5 * wp.randf(st)
            r = 0.2 + 0.2 * wp.randf(st)
            if (gx - ox) * (gx - ox) + (gy - oy) * (gy - oy) < r * r:
                a = a + (0.04 + 0.05 * wp.randf(st)) * w
    a = wp.max(a, 0.02)
    return wp.vec3(a, a * 0.99, a * 1.03)


@wp.func
def cement(seed: int, x: float, y: float, tint: float, fp: float) -> wp.vec3:
    slab = 1.5
    u = x / slab
    v = y / slab
    iu = int(wp.floor(u))
    iv = int(wp.floor(v))
    du = wp.min(u - float(iu), 1.0 - (u - float(iu))) * slab
    dv = wp.min(v - float(iv), 1.0 - (v - float(iv))) * slab
    a = 0.36 + 0.08 * tint + 0.05 * (hash01(seed + 21, iu, iv) - 0.5)
    a = a + 0.035 * wp.noise(wp.rand_init(seed + 22), wp.vec2(x * 2.5, y * 2.5))
    a = a + 0.02 * wp.noise(wp.rand_init(seed + 23), wp.vec2(x * 30.0, y * 30.0)) * fade(fp, 0.033)
    if wp.min(du, dv) < 0.008:
        a = a * (1.0 - 0.55 * fade(fp, 0.05))
    return wp.vec3(a * 1.02, a, a * 0.96)


@wp.func
def cobble_cell(x: float, y: float):
    """Running-bond stones of 0.18 x 0.11 m: (row, col, fu, fv) with fu, fv in [0, 1)."""
    v = y / 0.11
    row = int(wp.floor(v))
    u = x / 0.18 + 0.5 * float(row % 2)
    col = int(wp.floor(u))
    return row, col, u - float(col), v - float(row)


@wp.func
def cobblestone(seed: int, x: float, y: float, tint: float, fp: float) -> wp.vec3:
    row, col, fu, fv = cobble_cell(x, y)
    h = hash01(seed + 31, col, row)
    a = 0.16 + 0.10 * h + 0.04 * tint
    a = a + 0.02 * wp.noise(wp.rand_init(seed + 32), wp.vec2(x * 40.0, y * 40.0)) * fade(fp, 0.025)
    d = wp.min(wp.min(fu, 1.0 - fu) * 0.18, wp.min(fv, 1.0 - fv) * 0.11)
    w = fade(fp, 0.06)
    if d < 0.01:
        a = a * (1.0 - 0.6 * w)
    warm = 0.03 * (hash01(seed + 33, col, row) - 0.5)
    return wp.vec3(a + warm, a, a - warm)


@wp.func
def cobble_bump(x: float, y: float, n: wp.vec3, fp: float) -> wp.vec3:
    """Rounded stone tops: tilt the shading normal away from each stone's centre."""
    row, col, fu, fv = cobble_cell(x, y)
    k = 0.7 * fade(fp, 0.1)
    return wp.normalize(n + wp.vec3((fu - 0.5) * k, (fv - 0.5) * k, 0.0))


# --------------------------------------------------------------------------------- kernels
@wp.kernel
def gbuffer_kernel(mesh: wp.uint64, face_class: wp.array(dtype=wp.int32), face_inst: wp.array(dtype=wp.int32),
                   cam: Cam, max_t: float, background: int,
                   depth: wp.array(dtype=float), dist: wp.array(dtype=float), normal: wp.array(dtype=wp.vec3),
                   cls: wp.array(dtype=wp.int32), inst: wp.array(dtype=wp.int32), face: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    i = tid % cam.width
    j = tid // cam.width
    d, scale = cam_ray(cam, i, j)
    q = wp.mesh_query_ray(mesh, cam.pos, d, max_t)
    if q.result:
        n = q.normal
        if wp.dot(n, d) > 0.0:
            n = -n
        depth[tid] = q.t / scale
        dist[tid] = q.t
        normal[tid] = wp.transpose(cam.rot) * n
        cls[tid] = face_class[q.face]
        inst[tid] = face_inst[q.face]
        face[tid] = q.face
    else:
        depth[tid] = 0.0
        dist[tid] = 0.0
        normal[tid] = wp.vec3(0.0, 0.0, 0.0)
        cls[tid] = background
        inst[tid] = 0
        face[tid] = -1


@wp.kernel
def shade_kernel(mesh: wp.uint64, face_mat: wp.array(dtype=wp.int32), face_inst: wp.array(dtype=wp.int32),
                 face_tint: wp.array(dtype=float), cam: Cam, L: Light,
                 dist: wp.array(dtype=float), normal: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32),
                 rgb: wp.array(dtype=wp.vec3)):
    tid = wp.tid()
    i = tid % cam.width
    j = tid // cam.width
    d, scale = cam_ray(cam, i, j)
    f = face[tid]
    if f < 0:
        rgb[tid] = sky(d, L)
        return
    t = dist[tid]
    p = cam.pos + d * t
    n = cam.rot * normal[tid]
    fp = t / cam.fx  # metres per pixel at the hit, roughly
    mat = face_mat[f]
    tint = face_tint[f]
    defect = face_inst[f] > 0
    x = p[0]
    y = p[1]
    ns = n
    albedo = wp.vec3(0.0)
    if mat == 1:
        albedo = cobblestone(L.seed, x, y, tint, fp)
        ns = cobble_bump(x, y, n, fp)
    elif mat == 2:
        albedo = cement(L.seed, x, y, tint, fp)
    else:
        albedo = asphalt(L.seed, x, y, tint, fp)
    wet = L.wetness
    rough = 0.0
    if defect:
        # exposed base course: darker, grainier, holding water
        g = wp.noise(wp.rand_init(L.seed + 41), wp.vec2(x * 30.0, y * 30.0)) * fade(fp, 0.033)
        g2 = wp.noise(wp.rand_init(L.seed + 42), wp.vec2(x * 6.0, y * 6.0))
        albedo = albedo * (0.5 + 0.18 * g + 0.1 * g2) + wp.vec3(0.012, 0.008, 0.0)
        wet = wp.max(wet, 0.55)
        rough = 1.0
    albedo = albedo * (1.0 - 0.45 * wet)
    # sun: Lambert with a ray-traced shadow
    ndl = wp.dot(ns, L.sun_dir)
    vis = 1.0
    if ndl <= 0.0 or wp.dot(n, L.sun_dir) <= 0.0:
        vis = 0.0
    elif L.shadows != 0:
        if wp.mesh_query_ray_anyhit(mesh, p + n * 2.0e-3, L.sun_dir, 1.0e4):
            vis = 0.0
    sky_up = (L.sky_zenith + L.sky_horizon) * 0.5
    amb = sky_up * (L.ambient * (0.6 + 0.4 * ns[2]))
    c = wp.cw_mul(albedo, L.sun_rgb * (wp.max(ndl, 0.0) * vis) + amb)
    # specular sheen (Blinn-Phong) and sky reflection, both growing with wetness
    v = -d
    h = wp.normalize(L.sun_dir + v)
    shin = 30.0 + 400.0 * wet - 20.0 * rough
    ks = 0.02 + 0.5 * wet
    c = c + L.sun_rgb * (ks * wp.pow(wp.max(wp.dot(ns, h), 0.0), shin) * vis)
    cosv = wp.clamp(wp.dot(ns, v), 0.0, 1.0)
    fres = 0.02 + 0.98 * wp.pow(1.0 - cosv, 5.0)
    r = d - ns * (2.0 * wp.dot(d, ns))
    if r[2] < 0.02:
        r = wp.normalize(wp.vec3(r[0], r[1], 0.02))
    c = c + sky(r, L) * (fres * wet * 0.8)
    if L.fog_density > 0.0:
        k = wp.exp(-L.fog_density * t)
        c = c * k + L.fog_rgb * (1.0 - k)
    rgb[tid] = c


@wp.kernel
def occlusion_kernel(mesh: wp.uint64, cam: Cam, right_pos: wp.vec3, baseline: float,
                     dist: wp.array(dtype=float), depth: wp.array(dtype=float),
                     disparity: wp.array(dtype=float), occluded: wp.array(dtype=wp.int32)):
    """Left-view disparity f*B/Z and occlusion: a left pixel is occluded when the point it sees
    is hidden from the right camera (something nearer on the ray from the right centre) or falls
    outside the right image."""
    tid = wp.tid()
    z = depth[tid]
    if z <= 0.0:
        disparity[tid] = 0.0
        occluded[tid] = 0
        return
    i = tid % cam.width
    j = tid // cam.width
    d, scale = cam_ray(cam, i, j)
    p = cam.pos + d * dist[tid]
    disp = cam.fx * baseline / z
    disparity[tid] = disp
    occ = 0
    if float(i) - disp < -0.5:
        occ = 1
    else:
        to = p - right_pos
        ln = wp.length(to)
        if wp.mesh_query_ray_anyhit(mesh, right_pos, to / ln, ln * (1.0 - 1.0e-4) - 2.0e-3):
            occ = 1
    occluded[tid] = occ


@wp.kernel
def rays_kernel(cam: Cam, rays: wp.array2d(dtype=float)):
    """Primary rays as rows (origin, unit direction) for an external ray caster."""
    tid = wp.tid()
    d, scale = cam_ray(cam, tid % cam.width, tid // cam.width)
    for k in range(3):
        rays[tid, k] = cam.pos[k]
        rays[tid, 3 + k] = d[k]


@wp.kernel
def finish_kernel(face_class: wp.array(dtype=wp.int32), face_inst: wp.array(dtype=wp.int32), cam: Cam,
                  max_t: float, background: int, t_hit: wp.array(dtype=float), prim: wp.array(dtype=wp.int32),
                  nrm: wp.array(dtype=wp.vec3),
                  depth: wp.array(dtype=float), dist: wp.array(dtype=float), normal: wp.array(dtype=wp.vec3),
                  cls: wp.array(dtype=wp.int32), inst: wp.array(dtype=wp.int32), face: wp.array(dtype=wp.int32)):
    """The G-buffer kernel's outputs from an external caster's hits (t, face or -1, face normal)."""
    tid = wp.tid()
    d, scale = cam_ray(cam, tid % cam.width, tid // cam.width)
    t = t_hit[tid]
    f = prim[tid]
    if f >= 0 and t < max_t:
        n = nrm[tid]
        if wp.dot(n, d) > 0.0:
            n = -n
        depth[tid] = t / scale
        dist[tid] = t
        normal[tid] = wp.transpose(cam.rot) * n
        cls[tid] = face_class[f]
        inst[tid] = face_inst[f]
        face[tid] = f
    else:
        depth[tid] = 0.0
        dist[tid] = 0.0
        normal[tid] = wp.vec3(0.0, 0.0, 0.0)
        cls[tid] = background
        inst[tid] = 0
        face[tid] = -1


@wp.kernel
def probe_kernel(mesh: wp.uint64, origins: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                 t_out: wp.array(dtype=float), sign_out: wp.array(dtype=float)):
    tid = wp.tid()
    q = wp.mesh_query_ray(mesh, origins[tid], dirs[tid], 1.0e6)
    if q.result:
        t_out[tid] = q.t
        sign_out[tid] = q.sign
    else:
        t_out[tid] = -1.0
        sign_out[tid] = 0.0


# --------------------------------------------------------------------------------- host side
@dataclass
class LightSpec:
    """Host-side lighting and weather; ``light_preset`` gives the named ones. Radiance is in
    arbitrary linear units, roughly 1 for a bright sky (the writers tone-map with 1 - exp(-x))."""

    sun_elevation_deg: float = 45.0
    sun_azimuth_deg: float = 135.0
    sun_rgb: tuple = (1.7, 1.62, 1.5)
    sky_zenith: tuple = (0.3, 0.5, 0.95)
    sky_horizon: tuple = (0.95, 1.05, 1.2)
    ground_rgb: tuple = (0.12, 0.13, 0.1)
    ambient: float = 0.3
    fog_density: float = 0.0
    fog_rgb: tuple = (0.85, 0.87, 0.9)
    wetness: float = 0.0
    shadows: bool = True
    seed: int = 0


def light_preset(weather: str = "clear", **overrides) -> LightSpec:
    """clear (high white sun), fog (dim sun, exponential fog), wet (overcast, soaked road),
    dusk (low warm sun, orange horizon, long shadows). ``None`` overrides are ignored."""
    presets = {
        "clear": {},
        "fog": dict(sun_elevation_deg=35.0, sun_rgb=(0.8, 0.8, 0.8), sky_zenith=(0.75, 0.78, 0.82),
                    sky_horizon=(0.9, 0.92, 0.95), fog_density=0.045, fog_rgb=(0.85, 0.87, 0.9), ambient=0.6),
        "wet": dict(sun_elevation_deg=40.0, sun_rgb=(0.6, 0.6, 0.65), sky_zenith=(0.55, 0.58, 0.65),
                    sky_horizon=(0.8, 0.82, 0.88), wetness=1.0, ambient=0.6, fog_density=0.006,
                    fog_rgb=(0.75, 0.77, 0.8)),
        "dusk": dict(sun_elevation_deg=6.0, sun_rgb=(1.6, 0.75, 0.3), sky_zenith=(0.08, 0.1, 0.25),
                     sky_horizon=(0.9, 0.5, 0.28), ground_rgb=(0.05, 0.04, 0.04), ambient=0.35,
                     fog_rgb=(0.6, 0.4, 0.3)),
    }
    if weather not in presets:
        raise ValueError(f"unknown weather {weather!r} (known: {', '.join(presets)})")
    values = {**presets[weather], **{k: v for k, v in overrides.items() if v is not None}}
    return LightSpec(**values)


def make_light(spec: LightSpec) -> Light:
    el, az = math.radians(spec.sun_elevation_deg), math.radians(spec.sun_azimuth_deg)
    L = Light()
    L.sun_dir = wp.vec3(math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
    L.sun_rgb = wp.vec3(*spec.sun_rgb)
    L.sky_zenith = wp.vec3(*spec.sky_zenith)
    L.sky_horizon = wp.vec3(*spec.sky_horizon)
    L.ground_rgb = wp.vec3(*spec.ground_rgb)
    L.ambient = float(spec.ambient)
    L.fog_density = float(spec.fog_density)
    L.fog_rgb = wp.vec3(*spec.fog_rgb)
    L.wetness = float(spec.wetness)
    L.shadows = int(bool(spec.shadows))
    L.seed = int(spec.seed)
    return L


def make_cam(fx: float, fy: float, cx: float, cy: float, width: int, height: int,
             cam_to_world: np.ndarray) -> Cam:
    m = np.asarray(cam_to_world, dtype=np.float64)
    c = Cam()
    c.fx, c.fy, c.cx, c.cy = float(fx), float(fy), float(cx), float(cy)
    c.rot = wp.mat33(*m[:3, :3].astype(np.float32).ravel())
    c.pos = wp.vec3(*m[:3, 3].astype(np.float32))
    c.width, c.height = int(width), int(height)
    return c


class GBuffer:
    """Device arrays of one view; ``numpy()`` copies them to the host, shaped (H, W[, 3])."""

    FIELDS = ("depth", "dist", "normal", "cls", "inst", "face")

    def __init__(self, width: int, height: int, device):
        n = width * height
        self.width, self.height = width, height
        self.depth = wp.zeros(n, dtype=float, device=device)
        self.dist = wp.zeros(n, dtype=float, device=device)
        self.normal = wp.zeros(n, dtype=wp.vec3, device=device)
        self.cls = wp.zeros(n, dtype=wp.int32, device=device)
        self.inst = wp.zeros(n, dtype=wp.int32, device=device)
        self.face = wp.zeros(n, dtype=wp.int32, device=device)
        self.rgb = wp.zeros(n, dtype=wp.vec3, device=device)
        self.disparity = wp.zeros(n, dtype=float, device=device)
        self.occluded = wp.zeros(n, dtype=wp.int32, device=device)

    def numpy(self, fields=FIELDS) -> dict:
        h, w = self.height, self.width
        out = {}
        for f in fields:
            a = np.array(getattr(self, f).numpy(), copy=True)  # CPU arrays are views: copy
            out[f] = a.reshape(h, w, 3) if a.ndim == 2 else a.reshape(h, w)
        return out


class RaycastScene:
    """One triangle mesh with per-face labels on a warp device, and the kernels to view it."""

    def __init__(self, vertices, faces, face_class, face_instance, face_material, face_tint=None,
                 device=None, background_class: int = 0):
        self.device = wp.get_device(device)
        v = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
        f = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
        if len(f) == 0:
            raise ValueError("scene has no triangles")
        # float32 precision: keep the town near the origin (towns are a few km at most)
        self.points = wp.array(v, dtype=wp.vec3, device=self.device)
        self.indices = wp.array(f.ravel(), dtype=wp.int32, device=self.device)
        self.mesh = wp.Mesh(points=self.points, indices=self.indices)
        m = len(f)
        tint = np.zeros(m, np.float32) if face_tint is None else face_tint
        self.face_class = wp.array(np.asarray(face_class, np.int32).reshape(m), dtype=wp.int32, device=self.device)
        self.face_inst = wp.array(np.asarray(face_instance, np.int32).reshape(m), dtype=wp.int32, device=self.device)
        self.face_mat = wp.array(np.asarray(face_material, np.int32).reshape(m), dtype=wp.int32, device=self.device)
        self.face_tint = wp.array(np.asarray(tint, np.float32).reshape(m), dtype=float, device=self.device)
        self.background = int(background_class)
        self.max_t = 1.0e4
        self._buffers: dict = {}

    def buffer(self, width: int, height: int, slot: int = 0) -> GBuffer:
        key = (width, height, slot)
        if key not in self._buffers:
            self._buffers[key] = GBuffer(width, height, self.device)
        return self._buffers[key]

    def gbuffer(self, cam: Cam, out: GBuffer) -> GBuffer:
        wp.launch(gbuffer_kernel, dim=cam.width * cam.height, device=self.device,
                  inputs=[self.mesh.id, self.face_class, self.face_inst, cam, self.max_t, self.background],
                  outputs=[out.depth, out.dist, out.normal, out.cls, out.inst, out.face])
        return out

    def shade(self, cam: Cam, light: Light, gb: GBuffer) -> GBuffer:
        wp.launch(shade_kernel, dim=cam.width * cam.height, device=self.device,
                  inputs=[self.mesh.id, self.face_mat, self.face_inst, self.face_tint, cam, light,
                          gb.dist, gb.normal, gb.face], outputs=[gb.rgb])
        return gb

    def stereo(self, cam: Cam, right_pos, baseline: float, gb: GBuffer) -> GBuffer:
        wp.launch(occlusion_kernel, dim=cam.width * cam.height, device=self.device,
                  inputs=[self.mesh.id, cam, wp.vec3(*np.asarray(right_pos, np.float32)), float(baseline),
                          gb.dist, gb.depth], outputs=[gb.disparity, gb.occluded])
        return gb

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest hits of arbitrary rays: (t, sign); t = -1 where nothing is hit, sign > 0 for the
        front (winding) side of a face."""
        o = wp.array(np.asarray(origins, np.float32).reshape(-1, 3), dtype=wp.vec3, device=self.device)
        d = np.asarray(dirs, np.float64).reshape(-1, 3)
        d = wp.array((d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32), dtype=wp.vec3,
                     device=self.device)
        t = wp.zeros(len(o), dtype=float, device=self.device)
        s = wp.zeros(len(o), dtype=float, device=self.device)
        if len(o):
            wp.launch(probe_kernel, dim=len(o), device=self.device, inputs=[self.mesh.id, o, d], outputs=[t, s])
        return t.numpy(), s.numpy()

    def synchronize(self) -> None:
        wp.synchronize_device(self.device)

    # ---------------------------------------------------------- open3d (Embree) primary rays
    def enable_open3d(self) -> None:
        """CPU only: cast primary rays with open3d's RaycastingScene (Embree) instead of warp's
        scalar CPU BVH traversal; shading, shadows and occlusion stay in warp."""
        import open3d as o3d

        if self.device.is_cuda:
            raise ValueError("the open3d ray caster runs on the CPU only")
        self._o3d = o3d.t.geometry.RaycastingScene()
        self._o3d.add_triangles(o3d.core.Tensor(self.points.numpy()),
                                o3d.core.Tensor(self.indices.numpy().reshape(-1, 3).astype(np.uint32)))

    def gbuffer_open3d(self, cam: Cam, out: GBuffer) -> GBuffer:
        """The G-buffer kernel's outputs, with Embree doing the ray casting."""
        import open3d as o3d

        n = cam.width * cam.height
        if getattr(out, "_rays", None) is None or out._rays.shape[0] != n:
            out._rays = wp.zeros((n, 6), dtype=float, device=self.device)
        wp.launch(rays_kernel, dim=n, device=self.device, inputs=[cam], outputs=[out._rays])
        ans = self._o3d.cast_rays(o3d.core.Tensor.from_numpy(out._rays.numpy()))
        t = wp.array(ans["t_hit"].numpy(), dtype=float, device=self.device, copy=False)
        prim = wp.array(ans["primitive_ids"].numpy().view(np.int32), dtype=wp.int32, device=self.device, copy=False)
        nrm = wp.array(ans["primitive_normals"].numpy(), dtype=wp.vec3, device=self.device, copy=False)
        wp.launch(finish_kernel, dim=n, device=self.device,
                  inputs=[self.face_class, self.face_inst, cam, self.max_t, self.background, t, prim, nrm],
                  outputs=[out.depth, out.dist, out.normal, out.cls, out.inst, out.face])
        return out
