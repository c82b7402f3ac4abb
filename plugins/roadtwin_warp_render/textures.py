"""Material textures for the ray caster: one MIP-mapped atlas on a warp device and its filter.

Filtering is anisotropic (the approach of GPU anisotropic filtering, EXT_texture_filter_anisotropic
and Heckbert's elliptical footprint): the shade kernel passes the st derivatives of a pixel
(``dst_dx``, ``dst_dy``: st change across one pixel in x and in y, from ray differentials); the
pixel's footprint on the texture is the ellipse they span. Its minor axis picks the MIP level and
up to ``MAX_ANISO`` trilinear taps are spread along its major axis. On a road seen at a grazing
angle the footprint is several times longer along the road than across it: an isotropic level
(picked from the long axis, or from the mean of both) averages away what is thin across the view
(a 1-2 cm crack, a paint edge); this keeps it (tests/plugins/test_texture_filtering.py checks it
against a supersampled reference).

numpy + warp only, like ``raycast.py``, which imports from here.
"""
from __future__ import annotations

import numpy as np
import warp as wp

WRAP_MODES = {"repeat": 0, "clamp": 1, "mirror": 2}
MAX_ANISO = wp.constant(8)   # taps along the footprint's major axis at most (GPUs offer 2-16)


@wp.struct
class Textures:
    """Every material image in one atlas: MIP levels (box-filtered, level 0 first) of every
    map stored row-major one after the other, top row first. A map is an image with its levels;
    a material names its diffuse, roughness and (optional, -1) normal maps."""

    atlas: wp.array(dtype=wp.vec3)
    level_offset: wp.array(dtype=wp.int32)
    level_w: wp.array(dtype=wp.int32)
    level_h: wp.array(dtype=wp.int32)
    map_first: wp.array(dtype=wp.int32)     # first level of each map
    map_levels: wp.array(dtype=wp.int32)
    map_wrap_s: wp.array(dtype=wp.int32)    # 0 repeat, 1 clamp, 2 mirror
    map_wrap_t: wp.array(dtype=wp.int32)
    mat_diffuse: wp.array(dtype=wp.int32)
    mat_rough: wp.array(dtype=wp.int32)
    mat_normal: wp.array(dtype=wp.int32)
    mat_metallic: wp.array(dtype=float)
    mat_remap: wp.array(dtype=wp.int32)     # per-frame look: material id -> id whose maps are sampled
    mat_scale: wp.array(dtype=wp.vec3)      # per-frame look: diffuse multiplier, by the face's own id



@wp.func
def wrap_index(i: int, n: int, mode: int) -> int:
    """Texel index ``i`` folded into [0, n): 0 repeat, 1 clamp, 2 mirror."""
    r = int(0)
    if i >= 0 and i < n:
        r = i                       # inside: every mode leaves it (and no integer division, the filter's cost)
    elif mode == 1:
        r = wp.clamp(i, 0, n - 1)
    elif mode == 2:
        p = ((i % (2 * n)) + 2 * n) % (2 * n)
        r = p
        if p >= n:
            r = 2 * n - 1 - p
    else:
        r = ((i % n) + n) % n
    return r


@wp.func
def fold_coord(x: float, mode: int) -> float:
    """Texture coordinate reduced to one period before scaling to texels (float32 keeps
    sub-texel precision for st in the hundreds: a town a few km long)."""
    r = x
    if mode == 0:
        r = x - wp.floor(x)
    elif mode == 2:
        r = x - 2.0 * wp.floor(x * 0.5)
    return r


@wp.func
def texel(tex: Textures, off: int, w: int, i: int, j: int) -> wp.vec3:
    return tex.atlas[off + j * w + i]


@wp.func
def bilinear(tex: Textures, level: int, ws: int, wt: int, s: float, t: float) -> wp.vec3:
    """Bilinear lookup in one MIP level; st (0, 0) is the image's lower-left corner (USD)."""
    off = tex.level_offset[level]
    w = tex.level_w[level]
    h = tex.level_h[level]
    x = s * float(w) - 0.5
    y = (1.0 - t) * float(h) - 0.5
    x0 = wp.floor(x)
    y0 = wp.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = wrap_index(int(x0), w, ws)
    i1 = wrap_index(int(x0) + 1, w, ws)
    j0 = wrap_index(int(y0), h, wt)
    j1 = wrap_index(int(y0) + 1, h, wt)
    top = texel(tex, off, w, i0, j0) * (1.0 - fx) + texel(tex, off, w, i1, j0) * fx
    bot = texel(tex, off, w, i0, j1) * (1.0 - fx) + texel(tex, off, w, i1, j1) * fx
    return top * (1.0 - fy) + bot * fy


@wp.func
def trilinear(tex: Textures, first: int, n: int, ws: int, wt: int, s: float, t: float, lod: float) -> wp.vec3:
    """Bilinear lookups in MIP levels floor(lod) and the next coarser one, blended."""
    l0 = int(wp.floor(lod))
    f = lod - float(l0)
    c = bilinear(tex, first + l0, ws, wt, s, t)
    if f > 0.0 and l0 + 1 < n:
        c = c * (1.0 - f) + bilinear(tex, first + l0 + 1, ws, wt, s, t) * f
    return c


@wp.func
def major_axis(e: float, f: float, g: float, lam: float) -> wp.vec2:
    """Unit eigenvector of the symmetric 2x2 matrix [[e, f], [f, g]] for its eigenvalue ``lam``."""
    a = wp.vec2(f, lam - e)
    b = wp.vec2(lam - g, f)
    if wp.length_sq(b) > wp.length_sq(a):
        a = b
    if wp.length_sq(a) < 1.0e-20:
        a = wp.vec2(1.0, 0.0)
    return wp.normalize(a)


@wp.func
def sample_map(tex: Textures, m: int, s: float, t: float, dst_dx: wp.vec2, dst_dy: wp.vec2) -> wp.vec3:
    """Anisotropic lookup of map ``m`` at st (s, t) for a pixel whose st changes by ``dst_dx``
    and ``dst_dy`` across it: the footprint's axes are the singular values of that Jacobian in
    level-0 texels; the MIP level follows the minor axis (or major / MAX_ANISO where the
    ellipse is longer still) and ``ceil(major / minor)`` trilinear taps, equally weighted, cover
    the major axis. A round footprint is one trilinear lookup."""
    first = tex.map_first[m]
    n = tex.map_levels[m]
    ws = tex.map_wrap_s[m]
    wt = tex.map_wrap_t[m]
    if n == 1 and tex.level_w[first] * tex.level_h[first] == 1:
        return tex.atlas[tex.level_offset[first]]       # a constant: no filtering to do
    w0 = float(tex.level_w[first])
    h0 = float(tex.level_h[first])
    ax = dst_dx[0] * w0
    ay = dst_dx[1] * h0
    bx = dst_dy[0] * w0
    by = dst_dy[1] * h0
    e = ax * ax + bx * bx          # J J^T = [[e, f], [f, g]], J = [[ax, bx], [ay, by]]
    f = ax * ay + bx * by
    g = ay * ay + by * by
    mean = 0.5 * (e + g)
    root = wp.sqrt(wp.max(0.25 * (e - g) * (e - g) + f * f, 0.0))
    major = wp.sqrt(mean + root)
    minor = wp.sqrt(wp.max(mean - root, 0.0))
    taps = int(1)
    if major > 1.0e-6 and major > minor * 1.01:
        taps = wp.clamp(int(wp.ceil(major / wp.max(minor, 1.0e-8) - 0.01)), 1, MAX_ANISO)
    width = wp.max(major / float(taps), minor)
    lod = wp.clamp(wp.log2(wp.max(width, 1.0e-8)), 0.0, float(n - 1))
    su = fold_coord(s, ws)          # one period first: float32 keeps sub-texel precision
    tu = fold_coord(t, wt)
    c = wp.vec3(0.0, 0.0, 0.0)
    if taps == 1:
        c = trilinear(tex, first, n, ws, wt, su, tu, lod)
    else:
        u = major_axis(e, f, g, mean + root)
        step_s = u[0] * major / (w0 * float(taps))     # tap spacing along the major axis, in st
        step_t = u[1] * major / (h0 * float(taps))
        for k in range(taps):
            o = float(k) + 0.5 - 0.5 * float(taps)
            c = c + trilinear(tex, first, n, ws, wt, fold_coord(su + o * step_s, ws),
                              fold_coord(tu + o * step_t, wt), lod)
        c = c / float(taps)
    return c


def mip_levels(img: np.ndarray) -> list[np.ndarray]:
    """Box-filtered MIP pyramid (level 0 = the image) down to 1x1. An odd side is first padded
    with its own first row/column (the texture repeats), so a level's mean stays the image's
    mean for power-of-two sizes."""
    levels = [np.ascontiguousarray(img, dtype=np.float32)]
    a = levels[0]
    while a.shape[0] > 1 or a.shape[1] > 1:
        if a.shape[0] > 1:
            if a.shape[0] % 2:
                a = np.concatenate([a, a[:1]], axis=0)
            a = 0.5 * (a[0::2] + a[1::2])
        if a.shape[1] > 1:
            if a.shape[1] % 2:
                a = np.concatenate([a, a[:, :1]], axis=1)
            a = 0.5 * (a[:, 0::2] + a[:, 1::2])
        levels.append(np.ascontiguousarray(a, dtype=np.float32))
    return levels


def _rgb(img) -> np.ndarray:
    a = np.asarray(img, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return a[..., :3]


GREY = {"name": "default_grey", "diffuse": np.full((1, 1, 3), 0.18, np.float32),
        "roughness": np.full((1, 1, 1), 0.5, np.float32), "normal": None, "metallic": 0.0, "wrap": ("repeat", "repeat")}


def build_textures(materials: list[dict], device) -> tuple[Textures, int]:
    """Pack the materials' images (dicts: diffuse (H,W,3) linear, roughness (H,W,1), normal
    (H,W,3) or None, metallic, wrap (s, t)) with their MIP levels into one atlas. An image used
    by several materials is stored once. Returns the struct and the atlas size in texels."""
    maps: dict = {}
    chunks, lvl_off, lvl_w, lvl_h, first, nlev, wrap_s, wrap_t = [], [], [], [], [], [], [], []
    total = 0

    def add_map(img, wrap) -> int:
        nonlocal total
        key = (id(img), wrap)
        if key in maps:
            return maps[key]
        levels = mip_levels(_rgb(img))
        first.append(len(lvl_off))
        nlev.append(len(levels))
        wrap_s.append(WRAP_MODES.get(wrap[0], 0))
        wrap_t.append(WRAP_MODES.get(wrap[1], 0))
        for lv in levels:
            lvl_off.append(total)
            lvl_h.append(lv.shape[0])
            lvl_w.append(lv.shape[1])
            chunks.append(lv.reshape(-1, 3))
            total += lv.shape[0] * lv.shape[1]
        maps[key] = len(first) - 1
        return maps[key]

    md, mr, mn, mm = [], [], [], []
    for mat in materials:
        wrap = tuple(mat.get("wrap", ("repeat", "repeat")))
        md.append(add_map(mat["diffuse"], wrap))
        mr.append(add_map(mat["roughness"], wrap))
        mn.append(add_map(mat["normal"], wrap) if mat.get("normal") is not None else -1)
        mm.append(float(mat.get("metallic", 0.0)))
    if total >= 2 ** 31:
        raise ValueError(f"textures too large for one atlas ({total} texels)")
    tex = Textures()

    def ia(x):
        return wp.array(np.asarray(x, np.int32), dtype=wp.int32, device=device)

    # one copy of the texels into the atlas; on a CPU device warp uses that memory as it is
    # (tens of MB for a few 1024 px materials: each extra copy cost ~30 ms)
    atlas = np.empty((total, 3), np.float32)
    for off, chunk in zip(lvl_off, chunks):
        atlas[off:off + len(chunk)] = chunk
    device = wp.get_device(device)
    tex.atlas = wp.array(atlas, dtype=wp.vec3, device=device, copy=not device.is_cpu)
    tex.level_offset, tex.level_w, tex.level_h = ia(lvl_off), ia(lvl_w), ia(lvl_h)
    tex.map_first, tex.map_levels, tex.map_wrap_s, tex.map_wrap_t = ia(first), ia(nlev), ia(wrap_s), ia(wrap_t)
    tex.mat_diffuse, tex.mat_rough, tex.mat_normal = ia(md), ia(mr), ia(mn)
    tex.mat_metallic = wp.array(np.asarray(mm, np.float32), dtype=float, device=device)
    set_material_look(tex, np.arange(len(materials)), np.ones((len(materials), 3)), device)
    return tex, total


def checked_material_look(n: int, remap, scale) -> tuple[np.ndarray, np.ndarray]:
    """A per-frame material look for ``n`` materials as the kernels read it: remap (id -> id
    sampled, int32) and diffuse multipliers ((n, 3) float32); ValueError when it does not fit."""
    remap = np.asarray(remap, np.int32).reshape(-1)
    scale = np.asarray(scale, np.float32).reshape(-1, 3)
    if len(remap) != n or len(scale) != n or remap.min() < 0 or remap.max() >= n:
        raise ValueError(f"material look: expected {n} remap entries in range and {n} scales")
    return remap, scale


def set_material_look(tex: Textures, remap: np.ndarray, scale: np.ndarray, device) -> None:
    """Per-frame material remap (id -> id sampled) and diffuse multipliers (n_materials, 3)."""
    remap, scale = checked_material_look(tex.mat_diffuse.shape[0], remap, scale)
    tex.mat_remap = wp.array(remap, dtype=wp.int32, device=device)
    tex.mat_scale = wp.array(scale, dtype=wp.vec3, device=device)
