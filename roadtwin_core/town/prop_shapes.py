"""Procedural prototypes of the roadside world: small, low-poly triangle meshes (numpy; shapely for
posed footprints).

Each prototype is built once per town and stored once in the stage (a ``UsdGeom.PointInstancer``
prototype); every tree, pole or car is an instance of one. A prototype is a few *parts* (a tree:
trunk + crown), each a triangle mesh with a material name, in a local frame: Z up, metres, its
base at z = 0 on the origin, its length (cars, guardrail and fence sections, wires) along +X.

``footprint`` is what stands on the ground: the XY box of the parts that touch it (a tree's
trunk, not its crown; a fence section's posts and rails), used to keep props off the road.
``clearance_m``: the radius other props keep from its origin (a crown, a car's length).
Geometry depends only on the prototype's name: same town, same bytes.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import shapely

# material name -> (linear diffuse rgb, roughness, metallic)
PROP_MATERIALS: dict[str, tuple[tuple[float, float, float], float, float]] = {
    "bark": ((0.11, 0.075, 0.05), 0.9, 0.0),
    "leaves": ((0.06, 0.14, 0.035), 0.8, 0.0),
    "leaves_dark": ((0.035, 0.085, 0.03), 0.8, 0.0),
    "shrub": ((0.07, 0.12, 0.04), 0.85, 0.0),
    "dry_grass": ((0.30, 0.26, 0.12), 0.9, 0.0),
    "wood_pole": ((0.16, 0.12, 0.08), 0.85, 0.0),
    "concrete": ((0.42, 0.41, 0.39), 0.8, 0.0),
    "wire": ((0.03, 0.03, 0.03), 0.5, 0.3),
    "metal": ((0.45, 0.46, 0.48), 0.35, 0.8),
    "sign_blue": ((0.02, 0.10, 0.42), 0.4, 0.0),
    "sign_yellow": ((0.75, 0.55, 0.02), 0.4, 0.0),
    "sign_white": ((0.80, 0.80, 0.78), 0.4, 0.0),
    "sign_red": ((0.55, 0.03, 0.03), 0.4, 0.0),
    "fence_wood": ((0.22, 0.16, 0.10), 0.9, 0.0),
    "paint_red": ((0.45, 0.04, 0.03), 0.3, 0.0),
    "paint_white": ((0.75, 0.75, 0.74), 0.3, 0.0),
    "paint_grey": ((0.22, 0.23, 0.25), 0.3, 0.0),
    "paint_blue": ((0.04, 0.09, 0.30), 0.3, 0.0),
    "glass": ((0.02, 0.025, 0.03), 0.1, 0.0),
    "tyre": ((0.02, 0.02, 0.02), 0.9, 0.0),
    "hill_grass": ((0.10, 0.14, 0.06), 0.95, 0.0),
    "ground": ((0.12, 0.13, 0.07), 0.95, 0.0),
    "signal_green": ((0.02, 0.35, 0.08), 0.3, 0.0),
    "lamp_glass": ((0.7, 0.68, 0.6), 0.2, 0.0),
}

#: The UsdSemantics ``class`` labels props carry (a prototype's first label); readers tell a
#: prop from a road mesh by them, and class maps name them.
PROP_LABELS = ("vegetation", "pole", "sign", "vehicle", "terrain", "guardrail", "fence")

Mesh = tuple[np.ndarray, np.ndarray]


@dataclass
class Part:
    name: str
    vertices: np.ndarray      # (N,3) float64, prototype frame
    faces: np.ndarray         # (M,3) int64, counter-clockwise seen from outside
    material: str
    ground: bool = False      # stands on the ground (part of the footprint)


@dataclass
class Prototype:
    name: str
    label: str                # UsdSemantics class label
    parts: list[Part]
    clearance_m: float
    attach: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))   # wire attachment points (poles)

    @property
    def footprint(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the ground parts in the prototype frame."""
        v = np.concatenate([p.vertices for p in self.parts if p.ground] or [self.parts[0].vertices])
        return float(v[:, 0].min()), float(v[:, 1].min()), float(v[:, 0].max()), float(v[:, 1].max())

    def triangles(self) -> int:
        return sum(len(p.faces) for p in self.parts)


# ------------------------------------------------------------------------------ primitives
def box(sx: float, sy: float, sz: float, cx: float = 0.0, cy: float = 0.0, z0: float = 0.0) -> Mesh:
    x, y = sx / 2, sy / 2
    v = np.array([[cx - x, cy - y, z0], [cx + x, cy - y, z0], [cx + x, cy + y, z0], [cx - x, cy + y, z0],
                  [cx - x, cy - y, z0 + sz], [cx + x, cy - y, z0 + sz], [cx + x, cy + y, z0 + sz],
                  [cx - x, cy + y, z0 + sz]])
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                  [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return v, f


def frustum(r0: float, r1: float, h: float, n: int = 8, z0: float = 0.0, cap: bool = True) -> Mesh:
    """A cylinder / cone along +Z (``r1`` = 0: a cone with its tip)."""
    a = 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([np.cos(a), np.sin(a)])
    bottom = np.column_stack([ring * r0, np.full(n, z0)])
    faces = []
    if r1 > 0:
        top = np.column_stack([ring * r1, np.full(n, z0 + h)])
        v = np.concatenate([bottom, top, [[0, 0, z0], [0, 0, z0 + h]]])
        for i in range(n):
            j = (i + 1) % n
            faces += [[i, j, n + j], [i, n + j, n + i], [n + i, n + j, 2 * n + 1]]
            if cap:
                faces.append([i, 2 * n, j])
    else:
        v = np.concatenate([bottom, [[0, 0, z0 + h], [0, 0, z0]]])
        for i in range(n):
            j = (i + 1) % n
            faces.append([i, j, n])
            if cap:
                faces.append([i, n + 1, j])
    return v, np.array(faces)


def ellipsoid(rx: float, ry: float, rz: float, cz: float, seed: int = 0, bumps: float = 0.0,
              rings: int = 5, sectors: int = 9, half: bool = False) -> Mesh:
    """A UV ellipsoid (``half``: the dome above its equator, open at the bottom), its radius
    jittered by ``bumps`` (a seeded, fixed shape: the prototype's name picks the seed)."""
    rng = np.random.default_rng(seed)
    th = np.linspace(0, np.pi / 2 if half else np.pi, rings + 1)[1:] if half else np.linspace(0, np.pi, rings + 1)[1:-1]
    ph = 2 * np.pi * np.arange(sectors) / sectors
    t, p = np.meshgrid(th, ph, indexing="ij")
    r = 1.0 + bumps * rng.uniform(-1, 1, t.shape)
    pts = np.stack([np.sin(t) * np.cos(p) * rx * r, np.sin(t) * np.sin(p) * ry * r, np.cos(t) * rz * r + cz], -1)
    v = np.concatenate([[[0, 0, cz + rz]], pts.reshape(-1, 3)] + ([] if half else [[[0, 0, cz - rz]]]))
    faces = []
    nr = len(th)
    idx = lambda i, j: 1 + i * sectors + (j % sectors)  # noqa: E731
    for j in range(sectors):
        faces.append([0, idx(0, j), idx(0, j + 1)])
    for i in range(nr - 1):
        for j in range(sectors):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)
            faces += [[a, d, c], [a, c, b]]
    if not half:
        last = len(v) - 1
        for j in range(sectors):
            faces.append([last, idx(nr - 1, j + 1), idx(nr - 1, j)])
    return v, np.array(faces)


def wheel(radius: float, width: float, x: float, y: float, n: int = 8) -> Mesh:
    """A cylinder with its axis along Y, touching the ground at (x, y)."""
    v, f = frustum(radius, radius, width, n, -width / 2)
    v = v[:, [0, 2, 1]] * np.array([1.0, 1.0, 1.0])   # z -> y: swaps handedness, so flip faces
    v = v + np.array([x, y, radius])
    return v, f[:, ::-1]


def merge(*meshes: Mesh) -> Mesh:
    vs, fs, off = [], [], 0
    for v, f in meshes:
        vs.append(np.asarray(v, np.float64))
        fs.append(np.asarray(f, np.int64) + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def _part(name, mesh: Mesh, material, ground=False) -> Part:
    return Part(name, np.asarray(mesh[0], np.float64), np.asarray(mesh[1], np.int64), material, ground)


# ------------------------------------------------------------------------------ prototypes
def _seed(name: str) -> int:
    return sum((i + 1) * ord(c) for i, c in enumerate(name))


def _tree_round(name):
    s = _seed(name)
    return Prototype(name, "vegetation", [
        _part("trunk", frustum(0.2, 0.13, 3.2, 6), "bark", True),
        _part("crown", ellipsoid(2.2, 2.0, 1.9, 4.6, s, 0.12), "leaves")], clearance_m=2.5)


def _tree_conifer(name):
    return Prototype(name, "vegetation", [
        _part("trunk", frustum(0.18, 0.1, 2.0, 6), "bark", True),
        _part("crown", merge(frustum(1.7, 0.0, 4.2, 9, 1.5), frustum(1.2, 0.0, 3.4, 9, 4.0)), "leaves_dark")],
        clearance_m=2.0)


def _shrub(name):
    return Prototype(name, "vegetation", [_part("bush", ellipsoid(0.9, 0.8, 0.65, 0.45, _seed(name), 0.15, 4, 8),
                                                "shrub", True)], clearance_m=1.0)


def _grass(name):
    rng = np.random.default_rng(_seed(name))
    blades = []
    for k in range(7):
        a = 2 * np.pi * k / 7 + rng.uniform(-0.3, 0.3)
        r = rng.uniform(0.05, 0.3)
        v, f = frustum(0.05, 0.0, rng.uniform(0.5, 0.95), 3, cap=False)
        lean = rng.uniform(0.05, 0.25)
        v[:, 0] += np.cos(a) * (r + lean * v[:, 2])
        v[:, 1] += np.sin(a) * (r + lean * v[:, 2])
        blades.append((v, f))
    return Prototype(name, "vegetation", [_part("blades", merge(*blades), "dry_grass", True)], clearance_m=0.5)


def _pole(name):
    arm_z = 8.6
    return Prototype(name, "pole", [
        _part("shaft", frustum(0.14, 0.1, 9.0, 8), "wood_pole", True),
        _part("crossarm", box(0.1, 1.8, 0.1, 0.0, 0.0, arm_z - 0.1), "wood_pole")],
        clearance_m=1.0, attach=np.array([[0.0, -0.8, arm_z], [0.0, 0.8, arm_z]]))


def _wire(name):
    v, f = box(1.0, 0.025, 0.025, 0.5, 0.0, -0.0125)
    return Prototype(name, "pole", [_part("wire", (v, f), "wire")], clearance_m=0.0)


def _sign(name, face_material, plate: Mesh):
    return Prototype(name, "sign", [
        _part("post", frustum(0.04, 0.04, 2.5, 6), "metal", True),
        _part("plate", plate, face_material)], clearance_m=0.8)


def _sign_rect(name):
    return _sign(name, "sign_blue", box(0.04, 0.9, 0.6, 0.06, 0.0, 1.9))


def _sign_warning(name):
    v = np.array([[0.06, 0.0, 1.85], [0.06, 0.45, 2.3], [0.06, 0.0, 2.75], [0.06, -0.45, 2.3]])
    back = v - np.array([0.03, 0, 0])
    verts = np.concatenate([v, back])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]])
    return _sign(name, "sign_yellow", (verts, faces))


def _traffic_light(name):
    """A post with a three-lamp head facing +X (map signals that are dynamic)."""
    lamps = [box(0.05, 0.2, 0.2, 0.14, 0.0, z) for z in (3.35, 3.05, 2.75)]
    return Prototype(name, "sign", [
        _part("post", frustum(0.07, 0.06, 3.0, 8), "metal", True),
        _part("head", box(0.22, 0.34, 0.95, 0.0, 0.0, 2.7), "tyre"),
        _part("red", lamps[0], "sign_red"), _part("amber", lamps[1], "sign_yellow"),
        _part("green", lamps[2], "signal_green")], clearance_m=0.8)


def _street_lamp(name):
    """A 7.5 m metal pole with an arm reaching 1.6 m along +X and a lamp head at its end."""
    return Prototype(name, "pole", [
        _part("shaft", frustum(0.09, 0.06, 7.5, 8), "metal", True),
        _part("arm", box(1.7, 0.06, 0.06, 0.85, 0.0, 7.35), "metal"),
        _part("lamp", box(0.5, 0.25, 0.12, 1.5, 0.0, 7.25), "lamp_glass")], clearance_m=1.0)


def _km_post(name):
    return Prototype(name, "sign", [
        _part("post", box(0.14, 0.14, 1.0), "sign_white", True),
        _part("band", box(0.15, 0.15, 0.12, 0, 0, 0.8), "sign_red")], clearance_m=0.5)


def _guardrail(name):
    """A 4 m W-beam section from x = 0 to 4 with its post at x = 0 (sections chain end to end)."""
    return Prototype(name, "guardrail", [
        _part("post", box(0.12, 0.1, 0.75, 0.0, 0.0, 0.0), "metal", True),
        _part("beam", box(4.0, 0.06, 0.32, 2.0, -0.08, 0.45), "metal", True)], clearance_m=0.3)


def _fence(name):
    """A 3 m post-and-rail section from x = 0 to 3 with its post at x = 0."""
    return Prototype(name, "fence", [
        _part("post", box(0.1, 0.1, 1.3), "fence_wood", True),
        _part("rails", merge(box(3.0, 0.04, 0.07, 1.5, 0.0, 0.45), box(3.0, 0.04, 0.07, 1.5, 0.0, 1.05)),
              "fence_wood", True)], clearance_m=0.3)


def _vehicle(name, length, width, body_h, cabin, paint, wheels_x, wheel_r=0.33, clearance=None):
    """Body box on wheels, a cabin (glass box) on top; ``cabin`` = (length, x offset, height)."""
    parts = [_part("body", box(length, width, body_h, 0, 0, wheel_r), paint, True)]
    cl, cx, ch = cabin
    if cl > 0:
        parts.append(_part("cabin", box(cl, width * 0.9, ch, cx, 0, wheel_r + body_h), "glass"))
    ws = [wheel(wheel_r, 0.22, x, s * (width / 2 - 0.15)) for x in wheels_x for s in (-1, 1)]
    parts.append(_part("wheels", merge(*ws), "tyre", True))
    return Prototype(name, "vehicle", parts, clearance_m=clearance or length / 2 + 0.5)


def _car(paint):
    return lambda name: _vehicle(name, 4.4, 1.8, 0.75, (2.3, -0.2, 0.55), paint, (-1.35, 1.35), 0.32)


def _truck(name):
    p = _vehicle(name, 8.5, 2.5, 0.6, (0, 0, 0), "paint_white", (-2.8, -1.6, 2.7), 0.5)
    p.parts.append(_part("cargo", box(6.2, 2.5, 2.8, -1.05, 0, 1.1), "paint_white"))
    p.parts.append(_part("cab", box(2.0, 2.4, 1.5, 3.1, 0, 1.1), "paint_blue"))
    p.parts.append(_part("windscreen", box(0.05, 2.2, 0.7, 4.1, 0, 1.8), "glass"))
    return p


def _bus(name):
    p = _vehicle(name, 11.5, 2.5, 2.6, (0, 0, 0), "paint_grey", (-3.8, 3.6), 0.5)
    p.parts.append(_part("windows", box(10.6, 2.54, 0.85, 0.2, 0, 1.95), "glass"))
    return p


def _hill(name):
    """A unit dome (radius 1, height 1), scaled per instance to a distant hill."""
    return Prototype(name, "terrain", [_part("dome", ellipsoid(1.0, 1.0, 1.0, -0.05, _seed(name), 0.06, 5, 12,
                                                               half=True), "hill_grass", True)], clearance_m=0.0)


PROTOTYPES = {
    "tree_round": _tree_round, "tree_conifer": _tree_conifer, "shrub": _shrub, "grass_tuft": _grass,
    "utility_pole": _pole, "wire": _wire, "sign_rect": _sign_rect, "sign_warning": _sign_warning,
    "km_post": _km_post, "guardrail": _guardrail, "fence": _fence,
    "traffic_light": _traffic_light, "street_lamp": _street_lamp,
    "car_red": _car("paint_red"), "car_white": _car("paint_white"), "car_grey": _car("paint_grey"),
    "truck": _truck, "bus": _bus, "hill": _hill,
}


@functools.lru_cache(maxsize=None)
def make_prototype(name: str) -> Prototype:
    """The prototype (built once per process and shared: do not modify it)."""
    return PROTOTYPES[name](name)


def ground_grid(bounds: tuple[float, float, float, float], cell_m: float, apron_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid coordinates for the terrain under the town: ``cell_m`` apart over ``bounds``, then
    cells growing 1.6x a step outward until ``apron_m`` beyond them (cheap distant ground)."""
    def axis(lo, hi):
        n = max(1, int(math.ceil((hi - lo) / cell_m)))
        inner = np.linspace(lo, hi, n + 1)
        out, step, d = [], cell_m, 0.0
        while d < apron_m:
            step *= 1.6
            d = min(d + step, apron_m)
            out.append(d)
        out = np.array(out)
        return np.concatenate([lo - out[::-1], inner, hi + out])
    return axis(bounds[0], bounds[2]), axis(bounds[1], bounds[3])


def posed_footprints(protos: list[Prototype], idx, xy, yaw, scale):
    """World XY footprint boxes (shapely polygons) of posed instances."""
    fp = np.array([p.footprint for p in protos])[idx]          # (N, 4)
    sx, sy = scale[:, 0], scale[:, 1]
    corners = np.stack([fp[:, [0, 1]], fp[:, [2, 1]], fp[:, [2, 3]], fp[:, [0, 3]]], axis=1)
    corners = corners * np.stack([sx, sy], -1)[:, None, :]
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    wx = c * corners[..., 0] - s * corners[..., 1] + xy[:, None, 0]
    wy = s * corners[..., 0] + c * corners[..., 1] + xy[:, None, 1]
    return shapely.polygons(np.stack([wx, wy], -1))
