"""Ray-cast G-buffer and textured shading on warp: numpy + warp only.

This file imports nothing but numpy and warp (no USD). Everything is plain arrays:

- the scene is one ``wp.Mesh`` of all triangles (roads, defects, lane markings) with per-face
  arrays: semantic class id, instance id (0 = not a defect), material id and the texture
  coordinates (st) of the face's three corners;
- materials are images (what the stage's ``UsdPreviewSurface`` materials bind: linear diffuse,
  roughness, tangent-space normal map; constants are 1x1 images) packed into one atlas with
  box-filtered MIP levels (``textures.py``: ``build_textures``);
- a camera is a pinhole (fx, fy, cx, cy, width, height) with a camera-to-world rotation whose
  columns are the camera's x (right), y (down), z (forward) axes in world coordinates (OpenCV
  convention) and a centre; pixel (i, j) looks through image point (i, j) (pixel centres at
  integer coordinates, as in OpenCV's projection);
- the G-buffer holds, per pixel: z-depth along the optical axis (0 = no hit), ray length, the
  unit normal in camera coordinates (facing the camera), class, instance and face id (-1);
- shading turns a G-buffer into linear RGB radiance: st interpolated barycentrically at the hit,
  an anisotropic MIP lookup per map (``textures.py``: the pixel's st derivatives from ray
  differentials on the hit face's plane; repeat / clamp / mirror wrapping), the normal map applied in the face's tangent frame (the st
  gradient dP/ds, dP/dt: exact for world-planar and lane-aligned st alike), Lambert diffuse
  from a sun with ray-traced shadows plus sky ambient, a roughness-driven specular lobe, a sky
  gradient by direction, wet-road darkening and sky reflection, exponential fog.

World: Z up, metres. Nothing here knows about USD, files or the plugin manager.
"""
from __future__ import annotations

import math
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import warp as wp

from .textures import (GREY, WRAP_MODES, Textures, build_textures, mip_levels,  # noqa: F401 (re-exported)
                       checked_material_look, sample_map, set_material_look)

# nothing here is differentiated: no backward (adjoint) code, which cost most of the compile time
wp.set_module_options({"enable_backward": False})

CPU_THREADS = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
_LOADED: set = set()     # devices this module's kernels are loaded on
_LOAD_LOCK = threading.Lock()    # a warm-up thread and the first frame may ask at once


def load_kernels(device=None) -> None:
    """Compile this module's kernels for ``device`` now, or load them from warp's kernel cache.

    On a CPU without warp's precompiled headers: warp builds them anew in every process (they are
    not cached) and they only pay off from a process's second compiled module, so a first run
    (empty kernel cache) of the preview or a dataset compiles this one module ~0.7 s faster (3.2
    instead of 4.0 s on 2 cores). LLVM's options stay warp's defaults: with LLVM's own inlining
    thresholds it compiles in 2.3 s but shades 60 % slower (bench: 184 -> 294 ms a 800 x 480 frame).
    Safe to call from a thread started early, to compile while the caller does other work."""
    device = wp.get_device(device)
    with _LOAD_LOCK:
        if str(device) in _LOADED:
            return
        saved = wp.config.use_precompiled_headers
        if device.is_cpu:
            wp.config.use_precompiled_headers = False
        try:
            wp.load_module(module=sys.modules[__name__], device=device)
        finally:
            wp.config.use_precompiled_headers = saved
        _LOADED.add(str(device))


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


@wp.struct
class Faces:
    """Per-face shading data: material, st of the 3 corners (3 entries a face) and the st
    gradient (dP/ds, dP/dt: the tangent frame of normal maps)."""

    points: wp.array(dtype=wp.vec3)
    indices: wp.array(dtype=wp.int32)
    mat: wp.array(dtype=wp.int32)
    inst: wp.array(dtype=wp.int32)
    uv: wp.array(dtype=wp.vec2)
    tangent: wp.array(dtype=wp.vec3)
    bitangent: wp.array(dtype=wp.vec3)


SHADOW_OFFSET = wp.constant(2.0e-3)    # shadow rays start this far off the surface (m): no self-hits
SHADOW_MAX_T = wp.constant(1.0e4)


# --------------------------------------------------------------------------------- helpers
@wp.func
def cam_ray(cam: Cam, i: int, j: int):
    dc = wp.vec3((float(i) - cam.cx) / cam.fx, (float(j) - cam.cy) / cam.fy, 1.0)
    return wp.normalize(cam.rot * dc), wp.length(dc)


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
def tangent_frame(n: wp.vec3, tan: wp.vec3, bit: wp.vec3):
    """Unit tangent (along +s) and bitangent (along +t) orthogonal to ``n``, from the face's st
    gradient; where that is degenerate (st constant on the face) world X / Y stand in."""
    t = tan - n * wp.dot(n, tan)
    if wp.length(t) < 1.0e-6:
        t = wp.vec3(1.0, 0.0, 0.0) - n * n[0]
        if wp.length(t) < 1.0e-6:
            t = wp.vec3(0.0, 1.0, 0.0) - n * n[1]
    t = wp.normalize(t)
    b = bit - n * wp.dot(n, bit) - t * wp.dot(t, bit)
    if wp.length(b) < 1.0e-6:
        b = wp.cross(n, t)
    b = wp.normalize(b)
    return t, b


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


@wp.func
def barycentric(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    v0 = b - a
    v1 = c - a
    v2 = p - a
    d00 = wp.dot(v0, v0)
    d01 = wp.dot(v0, v1)
    d11 = wp.dot(v1, v1)
    d20 = wp.dot(v2, v0)
    d21 = wp.dot(v2, v1)
    den = d00 * d11 - d01 * d01
    w1 = float(0.0)
    w2 = float(0.0)
    if den != 0.0:
        w1 = (d11 * d20 - d01 * d21) / den
        w2 = (d00 * d21 - d01 * d20) / den
    return wp.vec3(1.0 - w1 - w2, w1, w2)


@wp.func
def face_st(F: Faces, f: int, q: wp.vec3) -> wp.vec2:
    """st at point ``q`` of face ``f``'s plane: its corners' st interpolated (extrapolated
    outside the triangle: st is affine on the face)."""
    bw = barycentric(q, F.points[F.indices[3 * f]], F.points[F.indices[3 * f + 1]], F.points[F.indices[3 * f + 2]])
    return F.uv[3 * f] * bw[0] + F.uv[3 * f + 1] * bw[1] + F.uv[3 * f + 2] * bw[2]


@wp.func
def plane_hit(cam: Cam, x: float, y: float, p: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Where the ray through image point (x, y) meets the plane through ``p`` with normal ``n``
    (facing the camera). A ray (nearly) parallel to the plane is taken to meet it at the
    incidence cosine 0.02: the footprint's stretch is bounded (50x) near the horizon."""
    r = cam.rot * wp.vec3((x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0)
    den = wp.min(wp.dot(r, n), -0.02 * wp.length(r))
    return cam.pos + r * (wp.dot(p - cam.pos, n) / den)


@wp.func
def st_derivatives(F: Faces, f: int, cam: Cam, i: int, j: int, p: wp.vec3, n: wp.vec3):
    """The st change across pixel (i, j) in x and in y (ray differentials: the rays through the
    pixel's edges meet the hit face's plane): the footprint the texture filter averages over."""
    x = float(i)
    y = float(j)
    dx = face_st(F, f, plane_hit(cam, x + 0.5, y, p, n)) - face_st(F, f, plane_hit(cam, x - 0.5, y, p, n))
    dy = face_st(F, f, plane_hit(cam, x, y + 0.5, p, n)) - face_st(F, f, plane_hit(cam, x, y - 0.5, p, n))
    return dx, dy


@wp.kernel
def shade_kernel(mesh: wp.uint64, F: Faces, tex: Textures, cam: Cam, L: Light,
                 dist: wp.array(dtype=float), normal: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32),
                 sun_vis: wp.array(dtype=float), first: int, rgb: wp.array(dtype=wp.vec3)):
    """``sun_vis``: the shadow test's answers per pixel (1 lit, 0 shadowed) from an external
    caster, or empty: the kernel casts its own shadow rays. ``first``: the launch's first pixel
    (a CPU frame is shaded in bands of rows, one thread each)."""
    tid = first + wp.tid()
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
    v = -d
    # texture coordinates: barycentric interpolation of the face's corner st; the pixel's
    # footprint in st (anisotropic: long along a road seen at a grazing angle, narrow across)
    uv = face_st(F, f, p)
    dst_dx, dst_dy = st_derivatives(F, f, cam, i, j, p, n)
    m0 = F.mat[f]
    m = tex.mat_remap[m0]
    albedo = wp.cw_mul(sample_map(tex, tex.mat_diffuse[m], uv[0], uv[1], dst_dx, dst_dy), tex.mat_scale[m0])
    rough = wp.clamp(sample_map(tex, tex.mat_rough[m], uv[0], uv[1], dst_dx, dst_dy)[0], 0.02, 1.0)
    metallic = tex.mat_metallic[m]
    ns = n
    nm_id = tex.mat_normal[m]
    if nm_id >= 0:
        nt = sample_map(tex, nm_id, uv[0], uv[1], dst_dx, dst_dy)
        if nt[2] > 1.0e-3:
            tt, bb = tangent_frame(n, F.tangent[f], F.bitangent[f])
            ns = wp.normalize(tt * nt[0] + bb * nt[1] + n * nt[2])
            if wp.dot(ns, v) < 0.0:      # a bump can not face away from the viewer
                ns = wp.normalize(ns - v * (wp.dot(ns, v) - 0.01))
    wet = L.wetness
    albedo = albedo * (1.0 - 0.45 * wet)
    spec_col = wp.vec3(0.04, 0.04, 0.04) * (1.0 - metallic) + albedo * metallic
    diffuse = albedo * (1.0 - metallic)
    # sun: Lambert with a ray-traced shadow
    ndl = wp.dot(ns, L.sun_dir)
    vis = 1.0
    if ndl <= 0.0 or wp.dot(n, L.sun_dir) <= 0.0:
        vis = 0.0
    elif L.shadows != 0:
        if sun_vis.shape[0] > 0:
            vis = sun_vis[tid]
        elif wp.mesh_query_ray_anyhit(mesh, p + n * SHADOW_OFFSET, L.sun_dir, SHADOW_MAX_T):
            vis = 0.0
    sky_up = (L.sky_zenith + L.sky_horizon) * 0.5
    amb = sky_up * (L.ambient * (0.6 + 0.4 * ns[2]))
    c = wp.cw_mul(diffuse, L.sun_rgb * (wp.max(ndl, 0.0) * vis) + amb)
    # sun specular: normalized Blinn-Phong lobe from the material's roughness (alpha = r^2,
    # exponent 2 / alpha^2 - 2), Schlick Fresnel, Kelemen visibility; a water film smooths it
    if vis > 0.0:
        r_eff = rough * (1.0 - 0.75 * wet)
        alpha = wp.max(r_eff * r_eff, 0.03)
        shin = wp.clamp(2.0 / (alpha * alpha) - 2.0, 1.0, 2000.0)
        h = wp.normalize(L.sun_dir + v)
        ndh = wp.max(wp.dot(ns, h), 0.0)
        vdh = wp.max(wp.dot(v, h), 0.05)
        fr = spec_col + (wp.vec3(1.0, 1.0, 1.0) - spec_col) * wp.pow(1.0 - vdh, 5.0)
        lobe = (shin + 2.0) / 8.0 * wp.pow(ndh, shin) / (vdh * vdh) * ndl
        c = c + wp.cw_mul(fr, L.sun_rgb) * lobe
    # sky reflection of a wet road (a mirror-like water film)
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
def sun_rays_kernel(cam: Cam, L: Light, dist: wp.array(dtype=float), normal: wp.array(dtype=wp.vec3),
                    face: wp.array(dtype=wp.int32), rays: wp.array2d(dtype=float)):
    """The shade kernel's shadow rays as rows (origin, direction) for an external caster: from
    each hit whose face looks at the sun, towards it; elsewhere a ray far above the town,
    pointing up (it meets nothing and costs nothing)."""
    tid = wp.tid()
    d, scale = cam_ray(cam, tid % cam.width, tid // cam.width)
    o = wp.vec3(0.0, 0.0, 1.0e9)
    s = wp.vec3(0.0, 0.0, 1.0)
    f = face[tid]
    if f >= 0:
        n = cam.rot * normal[tid]
        if wp.dot(n, L.sun_dir) > 0.0:
            o = cam.pos + d * dist[tid] + n * SHADOW_OFFSET
            s = L.sun_dir
    for k in range(3):
        rays[tid, k] = o[k]
        rays[tid, 3 + k] = s[k]


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
            arr = getattr(self, f)
            a = arr.numpy()                    # a new host array from a GPU; a view of a CPU array:
            if arr.device.is_cpu:              # copy that one (the buffer is reused next frame)
                a = a.copy()
            out[f] = a.reshape(h, w, 3) if a.ndim == 2 else a.reshape(h, w)
        return out


def face_st_frames(vertices: np.ndarray, faces: np.ndarray, face_uv: np.ndarray):
    """Per face: dP/ds and dP/dt (the st gradient, the tangent frame of normal maps). A face
    whose st is degenerate (constant or collinear) gets world X / Y."""
    p = vertices[faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = face_uv[:, 1] - face_uv[:, 0], face_uv[:, 2] - face_uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    ok = (np.abs(det) > 1e-12) & (area2 > 1e-14)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    tan = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    bit = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    tan[~ok] = (1.0, 0.0, 0.0)
    bit[~ok] = (0.0, 1.0, 0.0)
    return tan.astype(np.float32), bit.astype(np.float32)


class RaycastScene:
    """One triangle mesh with per-face labels and materials on a warp device, and the kernels
    to view it. ``face_uv`` (M, 3, 2): st per face corner; ``materials``: list of dicts (see
    :func:`build_textures`), ``face_material`` indexes it (default: one neutral grey)."""

    def __init__(self, vertices, faces, face_class, face_instance, face_material=None, face_uv=None,
                 materials=None, device=None, background_class: int = 0):
        self.device = wp.get_device(device)
        load_kernels(self.device)
        v = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
        f = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
        if len(f) == 0:
            raise ValueError("scene has no triangles")
        # float32 precision: keep the town near the origin (towns are a few km at most)
        self.points = wp.array(v, dtype=wp.vec3, device=self.device)
        self.indices = wp.array(f.ravel(), dtype=wp.int32, device=self.device)
        self.mesh = wp.Mesh(points=self.points, indices=self.indices)
        m = len(f)
        materials = list(materials) if materials else [GREY]
        fmat = np.zeros(m, np.int32) if face_material is None else np.asarray(face_material, np.int32).reshape(m)
        if fmat.min() < 0 or fmat.max() >= len(materials):
            raise ValueError("face material ids out of range")
        uv = np.zeros((m, 3, 2), np.float32) if face_uv is None else np.asarray(face_uv, np.float32).reshape(m, 3, 2)
        tan, bit = face_st_frames(v.astype(np.float64), f, uv.astype(np.float64))
        self.face_class = wp.array(np.asarray(face_class, np.int32).reshape(m), dtype=wp.int32, device=self.device)
        self.face_inst = wp.array(np.asarray(face_instance, np.int32).reshape(m), dtype=wp.int32, device=self.device)
        F = Faces()
        F.points, F.indices, F.inst = self.points, self.indices, self.face_inst
        F.mat = wp.array(fmat, dtype=wp.int32, device=self.device)
        F.uv = wp.array(uv.reshape(-1, 2), dtype=wp.vec2, device=self.device)
        F.tangent = wp.array(tan, dtype=wp.vec3, device=self.device)
        F.bitangent = wp.array(bit, dtype=wp.vec3, device=self.device)
        self.faces = F
        self.textures, self.texels = build_textures(materials, self.device)
        self.background = int(background_class)
        self.max_t = 1.0e4
        self._buffers: dict = {}
        self._o3d = None
        self._no_sun_vis = wp.zeros(0, dtype=float, device=self.device)
        self._pool, self._pool_pid = None, None

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
        sun_vis = self._no_sun_vis
        if self._o3d is not None and light.shadows:
            sun_vis = self.sun_visibility_open3d(cam, light, gb)
        inputs = [self.mesh.id, self.faces, self.textures, cam, light, gb.dist, gb.normal, gb.face, sun_vis]
        self._launch_bands(shade_kernel, cam, inputs, [gb.rgb])
        return gb

    def _launch_bands(self, kernel, cam: Cam, inputs: list, outputs: list) -> None:
        """Launch a per-pixel ``kernel`` (its last input: the launch's first pixel) over the frame:
        once on a GPU; on a CPU, where warp runs a launch on one thread, in bands of rows, 4 per
        core (the road's rows below the horizon cost more than the sky's), on a thread pool
        (warp's CPU launches release the GIL). Each pixel is shaded by the same code either way:
        the same bytes."""
        n = cam.width * cam.height
        if self.device.is_cuda or CPU_THREADS == 1:
            wp.launch(kernel, dim=n, device=self.device, inputs=inputs + [0], outputs=outputs)
            return
        if self._pool is None or self._pool_pid != os.getpid():      # a forked child has no pool threads
            self._pool, self._pool_pid = ThreadPoolExecutor(CPU_THREADS, thread_name_prefix="warp-cpu"), os.getpid()
        rows = np.linspace(0, cam.height, min(cam.height, 4 * CPU_THREADS) + 1).astype(int)
        jobs = [self._pool.submit(wp.launch, kernel, dim=int(b - a) * cam.width, device=self.device,
                                  inputs=inputs + [int(a) * cam.width], outputs=outputs)
                for a, b in zip(rows[:-1], rows[1:]) if b > a]
        for job in jobs:
            job.result()

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
        """CPU only: cast primary and shadow rays with open3d's RaycastingScene (Embree) instead
        of warp's scalar CPU BVH traversal; shading and stereo occlusion stay in warp."""
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

    def sun_visibility_open3d(self, cam: Cam, light: Light, gb: GBuffer) -> wp.array:
        """1 where the shade kernel's shadow ray (the same ray) reaches the sun, 0 where the town
        blocks it, Embree answering: the shadow rays were 40 % of a 1280x720 view's shading on
        warp's one CPU thread (bench/drive.py)."""
        import open3d as o3d

        n = cam.width * cam.height
        if getattr(gb, "_sun_rays", None) is None or gb._sun_rays.shape[0] != n:
            gb._sun_rays = wp.zeros((n, 6), dtype=float, device=self.device)
        wp.launch(sun_rays_kernel, dim=n, device=self.device, inputs=[cam, light, gb.dist, gb.normal, gb.face],
                  outputs=[gb._sun_rays])
        hit = self._o3d.test_occlusions(o3d.core.Tensor.from_numpy(gb._sun_rays.numpy()), tnear=0.0,
                                        tfar=float(SHADOW_MAX_T)).numpy()
        gb._sun_vis = np.logical_not(hit).astype(np.float32)          # kept alive while the kernel reads it
        return wp.array(gb._sun_vis, dtype=float, device=self.device, copy=False)
