"""Roads for the physics backends: straight ISO 8608 test roads with reference defects, a step,
and the crossings of a composed town (its baked collision mesh, the same mesh with the defects
filled in, and a path through each defect).

Every physics run here comes in pairs: the road *with* the defects and its *baseline*, the same
triangles with the defect vertices lifted back onto the surrounding road surface, so a run on the
baseline is the undisturbed twin of a run on the road (see ``metrics.py`` for why g needs it).

Test roads (``--surface``) are straight, one lane per defect so no run meets another defect,
built as tensor-product height grids (watertight: no T-junctions for a ray to slip through) with
a fine spacing (1 cm along travel, 2 cm across) over the defects and a coarse one (10 cm)
elsewhere, over an optional ISO 8608 surface (``roadtwin_core.surface``). Reference defects are
analytic so tests and the paper's two findings can be reproduced exactly (``REFERENCE_DEFECTS``:
``large_deep`` 1.2 m x 1.0 m x 8 cm and ``small_shallow`` 0.3 m x 0.3 m x 2.5 cm potholes):

* ``pothole``: elliptical footprint (length x width), flat floor at ``depth_m``, a straight wall
  ``wall_m`` wide (3 cm: near vertical, a broken asphalt edge).
* ``depression``: the same footprint with a cosine-bell profile (no edge).
* ``bump``: a cosine-bell hump of height ``depth_m`` (positive up).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import RoadtwinError


@dataclass
class RoadMesh:
    """A static road triangle mesh (world, meters, Z up)."""

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "road"

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        if len(self.faces) == 0:
            raise RoadtwinError(f"{self.name}: road mesh has no triangles")
        if not np.isfinite(self.vertices).all():
            raise RoadtwinError(f"{self.name}: road mesh has NaN or inf vertices")


@dataclass
class ReferenceDefect:
    """An analytic reference defect on a straight test road (travel along +x)."""

    id: str
    kind: str            # pothole | depression | bump
    x: float
    y: float
    length_m: float      # along travel
    width_m: float       # across
    depth_m: float       # depth (pothole, depression) or height (bump)
    wall_m: float = 0.03

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        a, b = self.length_m / 2, self.width_m / 2
        dx, dy = x - self.x, y - self.y
        rho = np.sqrt((dx / a) ** 2 + (dy / b) ** 2)
        if self.kind == "pothole":
            # distance inside the rim along the ray from the centre (exact on the axes)
            phi = np.arctan2(dy, dx)
            r_rim = 1.0 / np.sqrt((np.cos(phi) / a) ** 2 + (np.sin(phi) / b) ** 2)
            dist = (1.0 - rho) * r_rim
            return -self.depth_m * np.clip(dist / self.wall_m, 0.0, 1.0)
        bell = np.where(rho < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(rho, 1.0))), 0.0)
        if self.kind == "depression":
            return -self.depth_m * bell
        if self.kind == "bump":
            return self.depth_m * bell
        raise RoadtwinError(f"test defect {self.id}: unknown kind {self.kind!r} (pothole, depression, bump)")


# The paper's two cases: a large deep pothole (slowing down helps) and a small shallow one (a
# higher speed can help). Sizes are typical of the pothole library (2-10 cm deep).
REFERENCE_DEFECTS = (
    ("large_deep", "pothole", 1.2, 1.0, 0.08),
    ("small_shallow", "pothole", 0.30, 0.30, 0.025),
)


@dataclass
class Crossing:
    """A defect to drive over: a path through it and its extent along the path.

    ``path`` is a polyline through the defect centre in the travel direction, long enough for
    any run-up; ``s_center`` the defect centre's arclength along it; ``extent`` the footprint's
    (min, max) along travel relative to the centre.
    """

    defect_id: str
    defect_type: str
    path: np.ndarray
    s_center: float
    extent: tuple[float, float]
    depth_m: float = 0.0
    attributes: dict = field(default_factory=dict)
    limits: tuple[float, float] | None = None   # arclength range where the road is (None: unknown)


@dataclass
class Scenario:
    road: RoadMesh
    baseline: RoadMesh
    crossings: list[Crossing]
    source: str
    description: str = ""

    def crossing(self, defect_id: str) -> Crossing:
        for c in self.crossings:
            if c.defect_id == defect_id:
                return c
        known = ", ".join(c.defect_id for c in self.crossings[:20])
        more = "..." if len(self.crossings) > 20 else ""
        raise RoadtwinError(f"{self.source}: no defect {defect_id!r} (known: {known}{more})")

    def select(self, defect_ids: list[str] | None) -> "Scenario":
        if not defect_ids:
            return self
        chosen = [self.crossing(d) for d in defect_ids]
        return Scenario(self.road, self.baseline, chosen, self.source, self.description)


# ----------------------------------------------------------------------------- grids
def _axis(lo: float, hi: float, coarse: float, fine: float, fine_ranges: list[tuple[float, float]]) -> np.ndarray:
    pts = [np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / coarse)) + 1))]
    for a, b in fine_ranges:
        a, b = max(a, lo), min(b, hi)
        if b > a:
            pts.append(np.linspace(a, b, max(2, int(math.ceil((b - a) / fine)) + 1)))
    x = np.unique(np.round(np.concatenate(pts), 9))
    # drop nodes closer than a tenth of the fine spacing (from overlapping ranges)
    keep = np.concatenate([[True], np.diff(x) > fine * 0.1])
    return x[keep]


def grid_mesh(xs: np.ndarray, ys: np.ndarray, z: np.ndarray, name: str = "road") -> RoadMesh:
    """Triangulate a height grid z[j, i] at (xs[i], ys[j]) (counter-clockwise seen from +z)."""
    nx, ny = len(xs), len(ys)
    X, Y = np.meshgrid(xs, ys)
    v = np.column_stack([X.ravel(), Y.ravel(), np.asarray(z, dtype=np.float64).ravel()])
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    a = (j * nx + i).ravel()
    f = np.concatenate([np.column_stack([a, a + 1, a + nx + 1]), np.column_stack([a, a + nx + 1, a + nx])])
    return RoadMesh(v, f, name)


def _surface_heights(surface: str | None, bounds: tuple[float, float, float, float], seed: int):
    if surface is None or surface.strip().lower() in ("", "flat"):
        return lambda x, y: np.zeros_like(x)
    from ..surface import parse_surface   # scipy; vehicle imports with numpy alone (GPU side)

    surf = parse_surface(surface, bounds, seed)
    return lambda x, y: surf.height(np.column_stack([x.ravel(), y.ravel()])).reshape(x.shape)


def straight_road(length_m: float = 100.0, surface: str | None = None, defects: list[ReferenceDefect] | None = None,
                  seed: int = 0, width_m: float = 4.0, dx: float = 0.1, dx_fine: float = 0.01,
                  dy_fine: float = 0.02, y_center: float = 0.0) -> tuple[RoadMesh, RoadMesh]:
    """A straight road along +x from 0 to ``length_m``, y within width/2 of ``y_center``, with an
    optional ISO 8608 surface (``iso8608:C``) and analytic defects. Returns (road, baseline)."""
    if not (math.isfinite(length_m) and length_m > 0):
        raise RoadtwinError(f"road length must be > 0, got {length_m}")
    defects = defects or []
    fx = [(d.x - d.length_m / 2 - 0.1, d.x + d.length_m / 2 + 0.1) for d in defects]
    fy = [(d.y - d.width_m / 2 - 0.1, d.y + d.width_m / 2 + 0.1) for d in defects]
    xs = _axis(0.0, length_m, dx, dx_fine, fx)
    y0, y1 = y_center - width_m / 2, y_center + width_m / 2
    ys = _axis(y0, y1, dx, dy_fine, fy)
    X, Y = np.meshgrid(xs, ys)
    base = _surface_heights(surface, (0.0, y0, length_m, y1), seed)(X, Y)
    dz = np.zeros_like(X)
    for d in defects:
        dz += d.height(X, Y)
    tag = surface or "flat"
    return grid_mesh(xs, ys, base + dz, f"straight road {length_m:g} m ({tag})"), grid_mesh(
        xs, ys, base, f"straight road {length_m:g} m ({tag}), no defects")


def straight_road_scenario(length_m: float = 60.0, surface: str | None = None, seed: int = 0,
                       defects: list[ReferenceDefect] | None = None, lane_spacing_m: float = 4.5) -> Scenario:
    """The ``--surface`` scenario: a straight road of ``length_m`` along +x with one lane per
    defect (``lane_spacing_m`` apart), each reference defect centred in its own lane at
    x = 0.42 ``length_m``, so no run ever meets another defect. Or the given ``defects``."""
    if not (math.isfinite(length_m) and 10.0 <= length_m <= 5000.0):
        raise RoadtwinError(f"road length must be in [10, 5000] m, got {length_m}")
    if defects is None:
        defects = [ReferenceDefect(did, kind, 0.42 * length_m, k * lane_spacing_m, L, W, D)
                   for k, (did, kind, L, W, D) in enumerate(REFERENCE_DEFECTS)]
    ys = [d.y for d in defects] or [0.0]
    width = max(ys) - min(ys) + lane_spacing_m
    road, baseline = straight_road(length_m, surface, defects, seed, width_m=width,
                                   y_center=0.5 * (max(ys) + min(ys)))
    far = 300.0   # path beyond the road on both sides (float32 kernels: keep coordinates modest)
    crossings = [Crossing(d.id, d.kind, np.array([[d.x - far, d.y], [d.x + far, d.y]]), far,
                          (-d.length_m / 2, d.length_m / 2), d.depth_m,
                          {"length_m": d.length_m, "width_m": d.width_m, "depth_m": d.depth_m, "x": d.x, "y": d.y},
                          limits=(far - d.x, far - d.x + length_m))
                 for d in defects]
    return Scenario(road, baseline, crossings, f"straight road ({surface or 'flat'}, {length_m:g} m)",
                    "analytic reference defects, one lane each")


def step_road(length_m: float = 30.0, x_step: float = 10.0, height_m: float = 0.03, width_m: float = 4.0,
              dx: float = 0.05) -> RoadMesh:
    """A flat road with an (almost) vertical step of ``height_m`` at ``x_step`` (wall 0.1 mm)."""
    xs = np.unique(np.concatenate([np.arange(0.0, length_m + dx / 2, dx), [x_step - 1e-4, x_step]]))
    ys = np.linspace(-width_m / 2, width_m / 2, 5)
    X, Y = np.meshgrid(xs, ys)
    return grid_mesh(xs, ys, np.where(X >= x_step, height_m, 0.0), f"step {height_m} m")


# ----------------------------------------------------------------------------- paths for the backends
def resample_path(polyline: np.ndarray, ds: float = 0.5, heading_window_m: float = 2.0):
    """Uniform-arclength resampling of a polyline, with a smoothed, unwrapped heading.

    Every physics backend drives its vehicles along this same resampling, so that they follow
    the same path to the bit. A straight 2-point path stays 2 points (exact). Returns
    ``(xy (K,2), psi (K,), ds)``."""
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


def resampled_path_at(xy: np.ndarray, psi: np.ndarray, ds: float, s: np.ndarray):
    """Position (K,2), heading (K,) and heading change per meter (K,) at arclengths ``s`` of a
    :func:`resample_path` result, exactly as the kernels evaluate it: linear inside, straight
    beyond the ends (no turning there)."""
    u = np.asarray(s, dtype=np.float64) / ds
    k = np.clip(np.floor(u).astype(np.int64), 0, len(xy) - 2)
    f = u - k
    p = xy[k] + (xy[k + 1] - xy[k]) * f[:, None]
    fc = np.clip(f, 0.0, 1.0)
    yaw = psi[k] + (psi[k + 1] - psi[k]) * fc
    dyaw = np.where((f >= 0.0) & (f <= 1.0), (psi[k + 1] - psi[k]) / ds, 0.0)
    return p, yaw, dyaw


# ----------------------------------------------------------------------------- towns
def offset_polyline(poly: np.ndarray, d: float) -> np.ndarray:
    """Shift a polyline ``d`` meters to its left (vertex normals averaged over both segments)."""
    p = np.asarray(poly, dtype=np.float64)
    if d == 0:
        return p.copy()
    seg = np.diff(p, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    nrm = np.column_stack([-seg[:, 1], seg[:, 0]])
    vn = np.vstack([nrm[:1], nrm[:-1] + nrm[1:], nrm[-1:]])
    vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    return p + d * vn


def _project(poly: np.ndarray, pt: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(arclength, signed left offset, unit tangent) of pt's nearest point on a polyline."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    L = np.linalg.norm(ab, axis=1)
    u = np.clip(((pt - a) * ab).sum(1) / np.maximum(L, 1e-12) ** 2, 0, 1)
    q = a + ab * u[:, None]
    k = int(np.argmin(np.linalg.norm(q - pt, axis=1)))
    tang = ab[k] / max(L[k], 1e-12)
    s = float(np.concatenate([[0.0], np.cumsum(L)])[k] + u[k] * L[k])
    off = float(tang[0] * (pt[1] - q[k, 1]) - tang[1] * (pt[0] - q[k, 0]))
    return s, off, tang


def _segment_centerlines(scene) -> dict[str, np.ndarray]:
    """Lane centrelines of the town's road segments, by segment id (from the composed stage)."""
    out: dict[str, np.ndarray] = {}
    try:
        from pxr import Usd

        stage = Usd.Stage.Open(scene.source)
    except Exception:
        return out
    if stage is None:
        return out
    for r in scene.roads:
        prim = stage.GetPrimAtPath(r.path)
        if prim and prim.HasAttribute("roadtwin:segment:centerline"):
            c = prim.GetAttribute("roadtwin:segment:centerline").Get()
            if c is not None and len(c) >= 2:
                out[prim.GetName()] = np.asarray(c, dtype=np.float64).reshape(-1, 2)
    return out


class Occupancy:
    """Which 0.5 m cells of the plane the road mesh covers (triangle bounding boxes, so a slight
    over-approximation): enough to tell where a path leaves the road."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, cell: float = 0.5) -> None:
        tri = vertices[faces][:, :, :2]
        lo = tri.min(axis=1)
        hi = tri.max(axis=1)
        self.cell = cell
        self.origin = lo.min(axis=0) - cell
        i0 = np.floor((lo - self.origin) / cell).astype(np.int64)
        i1 = np.floor((hi - self.origin) / cell).astype(np.int64)
        shape = i1.max(axis=0) + 2
        self.shape = (int(shape[0]), int(shape[1]))
        grid = np.zeros(self.shape, dtype=bool)
        span = i1 - i0
        small = (span <= 3).all(axis=1)
        for dx in range(4):
            for dy in range(4):
                m = small & (span[:, 0] >= dx) & (span[:, 1] >= dy)
                grid[i0[m, 0] + dx, i0[m, 1] + dy] = True
        for k in np.flatnonzero(~small):
            grid[i0[k, 0]: i1[k, 0] + 1, i0[k, 1]: i1[k, 1] + 1] = True
        self.grid = grid

    def covered(self, xy: np.ndarray) -> np.ndarray:
        ij = np.floor((np.asarray(xy) - self.origin) / self.cell).astype(np.int64)
        ok = (ij >= 0).all(axis=1) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] < self.shape[1])
        out = np.zeros(len(ij), dtype=bool)
        out[ok] = self.grid[ij[ok, 0], ij[ok, 1]]
        return out


def path_point(path: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit tangents at arclengths s along a polyline (clamped to its ends)."""
    seg = np.diff(path, axis=0)
    L = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(L)])
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, cum[-1])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    u = (s - cum[k]) / np.maximum(L[k], 1e-12)
    tang = seg[k] / np.maximum(L[k], 1e-12)[:, None]
    return path[k] + seg[k] * u[:, None], tang


def road_limits(occ: Occupancy, path: np.ndarray, s_center: float, half_width: float = 1.2,
                reach: float = 150.0, step: float = 0.25) -> tuple[float, float]:
    """The stretch of ``path`` around ``s_center`` where the road covers a band of
    +-``half_width`` (the wheel tracks), from the occupancy grid."""
    s = np.arange(s_center - reach, s_center + reach + step / 2, step)
    p, t = path_point(path, s)
    n = np.column_stack([-t[:, 1], t[:, 0]])
    ok = np.ones(len(s), dtype=bool)
    for lat in np.linspace(-half_width, half_width, 5):
        ok &= occ.covered(p + n * lat)
    k = int(np.argmin(np.abs(s - s_center)))
    if not ok[k]:
        return s_center, s_center
    lo = k
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    hi = k
    while hi < len(s) - 1 and ok[hi + 1]:
        hi += 1
    return float(s[lo]), float(s[hi])


def fill_defects(vertices: np.ndarray, defects) -> np.ndarray:
    """The collision mesh's vertices with every defect's interior lifted back onto the road.

    A defect's baked pieces share their rim vertices with the road (pseudo-height = surface);
    its interior vertices get the height of the rim surface interpolated over the footprint
    (linear on the rim's Delaunay triangulation, a least-squares plane outside it)."""
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import QhullError
    from scipy.spatial import cKDTree

    v = np.array(vertices, dtype=np.float64, copy=True)
    tree = cKDTree(v)
    for d in defects:
        for piece in d.pieces:
            pv, pf = piece.vertices, piece.faces
            if len(pf) == 0:
                continue
            edges = np.sort(np.concatenate([pf[:, [0, 1]], pf[:, [1, 2]], pf[:, [2, 0]]]), axis=1)
            uniq, counts = np.unique(edges, axis=0, return_counts=True)
            rim = np.unique(uniq[counts == 1])
            inner = np.setdiff1d(np.arange(len(pv)), rim)
            if len(inner) == 0 or len(rim) < 3:
                continue
            rxy, rz = pv[rim, :2], pv[rim, 2]
            A = np.column_stack([np.ones(len(rim)), rxy])
            plane = np.linalg.lstsq(A, rz, rcond=None)[0]
            z = plane[0] + pv[inner, :2] @ plane[1:]
            try:
                lin = LinearNDInterpolator(rxy, rz)(pv[inner, :2])
                z = np.where(np.isfinite(lin), lin, z)
            except QhullError:  # degenerate rim (collinear): keep the plane
                pass
            dist, idx = tree.query(pv[inner], distance_upper_bound=1e-6)
            ok = np.isfinite(dist)
            v[idx[ok], 2] = z[ok]
    return v


def town_scenario(scene, defect_ids: list[str] | None = None, reach_m: float = 300.0) -> Scenario:
    """Crossings of a composed town: for each defect a path along its segment's lane centreline
    (``roadtwin:segment:centerline`` from the layout, shifted sideways to run through the defect
    centre, extended straight beyond its ends), or a straight line along the segment's long axis
    where the layout has no centreline. The stretch where the road covers the wheel tracks
    (+-1.2 m) around the defect is taken from an occupancy grid of the collision mesh, so runs
    are clipped to it instead of driving off the mesh. Known limit: a path does not follow the
    next segment round a bend; a run whose wheels leave the mesh is flagged ``off_road``."""
    verts, faces = scene.collision_mesh()  # raises if the stage has none
    defects = scene.defects if not defect_ids else [scene.defect(d) for d in defect_ids]
    if not defects:
        raise RoadtwinError(f"{scene.source}: the town has no defects to cross")
    centerlines = _segment_centerlines(scene)
    roads = {r.path.rsplit("/", 1)[-1]: r for r in scene.roads}
    crossings = []
    for d in defects:
        pose = d.attributes.get("poseXYYaw")
        if pose is None:
            raise RoadtwinError(f"{scene.source}: defect {d.id} has no roadtwin:defect:poseXYYaw")
        c = np.array([float(pose[0]), float(pose[1])])
        segs = [str(s) for s in (d.attributes.get("segments") or [])]
        line = next((centerlines[s] for s in segs if s in centerlines), None)
        if line is not None:
            s_c, off, tang = _project(line, c)
            line = offset_polyline(line, off)
            s_c, _, tang = _project(line, c)
        else:
            seg = next((roads[s] for s in segs if s in roads), None)
            pts = (seg.vertices[:, :2] if seg is not None else d.mesh()[0][:, :2])
            pts = pts - pts.mean(0)
            tang = np.linalg.svd(pts, full_matrices=False)[2][0]
            line = np.array([c - tang, c + tang])
            s_c = 1.0
        # straight extensions at both ends so any run-up fits
        t0 = line[1] - line[0]
        t1 = line[-1] - line[-2]
        t0, t1 = t0 / np.linalg.norm(t0), t1 / np.linalg.norm(t1)
        path = np.vstack([line[0] - t0 * reach_m, line, line[-1] + t1 * reach_m])
        s_c += reach_m
        pv = d.mesh()[0]
        along = (pv[:, :2] - c) @ tang if len(pv) else np.array([-0.25, 0.25])
        crossings.append(Crossing(d.id, d.defect_type, path, float(s_c), (float(along.min()), float(along.max())),
                                  float(d.attributes.get("depthM", 0.0) or 0.0), dict(d.attributes)))
    road = RoadMesh(verts, faces, f"{scene.source} collision")
    occ = Occupancy(road.vertices, road.faces)
    for c in crossings:
        c.limits = road_limits(occ, c.path, c.s_center)
    baseline = RoadMesh(fill_defects(verts, scene.defects), faces, f"{scene.source} collision, defects filled")
    return Scenario(road, baseline, crossings, scene.source, f"town {scene.name}")


def load_town_scenario(stage_path, defect_ids: list[str] | None = None) -> Scenario:
    from ..usd.town_reader import load_town   # pxr; GPU machines have no USD

    return town_scenario(load_town(stage_path), defect_ids)
