"""Grid maps of a composed town for path planning (docs/architecture.md#data-flow:
town stage -> rasterize 0.2 m).

A :class:`GridMap` is a set of aligned 2D arrays over an axis-aligned window of the town, one
cell per ``resolution`` metres (0.2 m as in Zhang et al.). Cell ``[iy, ix]`` covers
``[x0 + ix*res, x0 + (ix+1)*res) x [y0 + iy*res, y0 + (iy+1)*res)``; a cell *is* what its centre
is (centre sampling: a cell belongs to a triangle when its centre lies inside it). Maps made by
:func:`rasterize_scene` put cell centres a quarter cell off round coordinates.

* ``drivable``  the lanes: cells of road segments of the drivable kinds (driving, junction) plus
  the defect cells lying on them (a merged road has holes where its defects are).
* ``defect``    cells inside a defect's baked mesh; ``defect_index`` says which defect. A defect
  thinner than a cell on average (2 area / perimeter < resolution: a crack, a tiny pothole) would
  mostly vanish under centre sampling, so every cell one of its vertices falls in counts too.
* ``depth``     per defect cell, the surrounding road height minus the defect surface height
  (m, positive below the road, negative for bumps). The surrounding road height is a plane fitted
  to the road cells in a ring around the defect, so it follows a sloped or rough road.
* ``height``    road surface height (z) of each drivable cell, defects included (for path Z).
* ``distance``  Euclidean distance (m) from each cell centre to the nearest defect cell centre
  (scipy's exact EDT; 0 on defects, +inf when the map has no defect).

The rasterizer is plain numpy: every (triangle, candidate cell) pair inside the triangle's
bounding box is tested with barycentric coordinates in one vectorised pass, in chunks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..errors import RoadtwinError
from ..usd.town_reader import TownScene, load_town

DRIVABLE_KINDS = ("driving", "junction")
MAX_CELLS = 25_000_000
_CHUNK = 4_000_000


@dataclass
class GridMap:
    origin: tuple[float, float]          # world (x, y) of the lower-left corner of cell [0, 0]
    resolution: float                    # cell size (m)
    drivable: np.ndarray                 # (ny, nx) bool
    defect: np.ndarray                   # (ny, nx) bool
    depth: np.ndarray                    # (ny, nx) float32, 0 outside defects
    height: np.ndarray                   # (ny, nx) float32, NaN where not drivable
    distance: np.ndarray                 # (ny, nx) float32, m to the nearest defect cell centre
    defect_index: np.ndarray             # (ny, nx) int32, -1 outside defects
    defect_ids: list[str] = field(default_factory=list)
    defect_types: list[str] = field(default_factory=list)
    source: str = ""
    name: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(cls, origin, resolution: float, drivable: np.ndarray, defect: np.ndarray | None = None,
              depth: np.ndarray | None = None, height: np.ndarray | None = None,
              defect_index: np.ndarray | None = None, defect_ids: Iterable[str] = (),
              defect_types: Iterable[str] = (), **kw) -> "GridMap":
        """A map from masks (tests, other sources); fills what is not given and the distance field."""
        drivable = np.asarray(drivable, dtype=bool)
        shape = drivable.shape
        defect = np.zeros(shape, bool) if defect is None else np.asarray(defect, dtype=bool)
        if defect.shape != shape:
            raise RoadtwinError(f"grid map: defect mask shape {defect.shape} != drivable {shape}")
        if defect_index is None:
            defect_index = np.where(defect, 0, -1).astype(np.int32)
            defect_ids = list(defect_ids) or (["defect"] if defect.any() else [])
        depth = np.zeros(shape, np.float32) if depth is None else np.asarray(depth, dtype=np.float32)
        height = (np.where(drivable, 0.0, np.nan) if height is None else np.asarray(height)).astype(np.float32)
        ids = list(defect_ids)
        types = list(defect_types) or ["unknown"] * len(ids)
        return cls((float(origin[0]), float(origin[1])), float(resolution), drivable, defect, depth, height,
                   distance_field(defect, resolution), np.asarray(defect_index, dtype=np.int32), ids, types, **kw)

    # ------------------------------------------------------------------ geometry helpers
    @property
    def shape(self) -> tuple[int, int]:
        return self.drivable.shape

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the whole map, for imshow."""
        ny, nx = self.shape
        x0, y0 = self.origin
        return x0, x0 + nx * self.resolution, y0, y0 + ny * self.resolution

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ix, iy) integer cell indices of world points (may lie outside the map)."""
        xy = np.asarray(xy, dtype=np.float64)
        ix = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        iy = np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return ix, iy

    def cell_to_world(self, ix, iy) -> np.ndarray:
        """World (x, y) of cell centres."""
        ix, iy = np.asarray(ix), np.asarray(iy)
        return np.stack([self.origin[0] + (ix + 0.5) * self.resolution,
                         self.origin[1] + (iy + 0.5) * self.resolution], axis=-1)

    def inside(self, ix, iy) -> np.ndarray:
        ny, nx = self.shape
        return (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)

    def sample(self, array: np.ndarray, xy: np.ndarray, fill: Any = 0) -> np.ndarray:
        """Nearest-cell lookup of ``array`` at world points; ``fill`` outside the map."""
        ix, iy = self.world_to_cell(xy)
        ok = self.inside(ix, iy)
        out = np.full(ix.shape, fill, dtype=np.result_type(array.dtype, np.asarray(fill).dtype))
        out[ok] = array[iy[ok], ix[ok]]
        return out

    def road_height(self, xy: np.ndarray, defects: bool = False) -> np.ndarray:
        """Road height under world points (nearest drivable cell when the point's cell has none).

        Without ``defects`` a defect cell reports the surrounding road level (height + depth),
        e.g. for a path whose rear-axle centre passes over a pothole between the wheels."""
        level = self.height if defects else self.height + np.where(self.defect, self.depth, 0).astype(np.float32)
        z = self.sample(level, xy, np.nan).astype(np.float64)
        if np.isnan(z).any():
            filled = self._filled_height()
            ix, iy = self.world_to_cell(xy)
            ny, nx = self.shape
            ix, iy = np.clip(ix, 0, nx - 1), np.clip(iy, 0, ny - 1)
            z = np.where(np.isnan(z), filled[iy, ix], z)
        return z

    def _filled_height(self) -> np.ndarray:
        if not hasattr(self, "_filled"):
            known = np.isfinite(self.height)
            if not known.any():
                self._filled = np.zeros(self.shape, np.float32)
            else:
                idx = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
                self._filled = self.height[tuple(idx)]
        return self._filled

    def defect_centres(self) -> np.ndarray:
        """World centres of all defect cells, (K, 2)."""
        iy, ix = np.nonzero(self.defect)
        return self.cell_to_world(ix, iy)

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Exact distance (m) from world points to the nearest defect cell centre (+inf if none)."""
        xy = np.asarray(xy, dtype=np.float64)
        if not self.defect.any():
            return np.full(xy.shape[:-1], np.inf)
        if not hasattr(self, "_tree"):
            self._tree = cKDTree(self.defect_centres())
        d, _ = self._tree.query(xy.reshape(-1, 2))
        return d.reshape(xy.shape[:-1])

    def defect_name(self, index: int) -> str:
        return self.defect_ids[index] if 0 <= index < len(self.defect_ids) else f"#{index}"

    def summary(self) -> dict[str, Any]:
        cell = self.resolution ** 2
        return {"origin": list(self.origin), "resolution_m": self.resolution, "shape": list(self.shape),
                "drivable_area_m2": float(self.drivable.sum() * cell),
                "defect_area_m2": float(self.defect.sum() * cell), "defects": len(self.defect_ids),
                "max_depth_m": float(self.depth.max()) if self.defect.any() else 0.0}


def distance_field(defect: np.ndarray, resolution: float) -> np.ndarray:
    """EDT in metres from every cell centre to the nearest defect cell centre (+inf if none)."""
    if not defect.any():
        return np.full(defect.shape, np.inf, np.float32)
    return ndimage.distance_transform_edt(~defect, sampling=resolution).astype(np.float32)


# ---------------------------------------------------------------------- rasterization
def rasterize_triangles(tris: np.ndarray, origin: tuple[float, float], resolution: float,
                        shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells whose centre lies inside a triangle (edges included, so shared edges leave no gap).

    ``tris`` is (T, 3, 3) world xyz. Returns ``(flat_cell_index, triangle_index, z)`` with z
    interpolated barycentrically at the cell centre; a cell on a shared edge may appear twice.
    """
    tris = np.asarray(tris, dtype=np.float64)
    ny, nx = shape
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(tris) == 0:
        return empty
    x0, y0 = origin
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = tris[:, :, :2].min(axis=1)
    hi = tris[:, :, :2].max(axis=1)
    # Cells whose centre x0 + (i + 0.5) res lies in [lo, hi].
    i0 = np.maximum(np.ceil((lo - (x0, y0)) / resolution - 0.5), 0).astype(np.int64)
    i1 = np.minimum(np.floor((hi - (x0, y0)) / resolution - 0.5), (nx - 1, ny - 1)).astype(np.int64)
    w = np.maximum(i1[:, 0] - i0[:, 0] + 1, 0)
    h = np.maximum(i1[:, 1] - i0[:, 1] + 1, 0)
    count = w * h
    keep = np.flatnonzero((count > 0) & (np.abs(det) > 1e-14))
    if len(keep) == 0:
        return empty
    out_cells, out_tris, out_z = [], [], []
    csum = np.cumsum(count[keep])
    start = 0
    while start < len(keep):
        base = csum[start - 1] if start else 0
        stop = int(np.searchsorted(csum, base + _CHUNK, side="right"))
        stop = max(stop, start + 1)
        t = keep[start:stop]
        n = count[t]
        ti = np.repeat(t, n)
        off = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        ix = i0[ti, 0] + off % w[ti]
        iy = i0[ti, 1] + off // w[ti]
        px = x0 + (ix + 0.5) * resolution
        py = y0 + (iy + 0.5) * resolution
        A, B, C, D = a[ti], b[ti], c[ti], det[ti]
        l1 = ((B[:, 0] - px) * (C[:, 1] - py) - (B[:, 1] - py) * (C[:, 0] - px)) / D
        l2 = ((C[:, 0] - px) * (A[:, 1] - py) - (C[:, 1] - py) * (A[:, 0] - px)) / D
        l3 = 1.0 - l1 - l2
        eps = -1e-9
        ok = (l1 >= eps) & (l2 >= eps) & (l3 >= eps)
        out_cells.append(iy[ok] * nx + ix[ok])
        out_tris.append(ti[ok])
        out_z.append(l1[ok] * A[ok, 2] + l2[ok] * B[ok, 2] + l3[ok] * C[ok, 2])
        start = stop
    return np.concatenate(out_cells), np.concatenate(out_tris), np.concatenate(out_z)


def _boundary_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total length of the edges used by one face only (the outline, holes included). Vertices
    are welded by position first, so pieces of one defect cut by a segment border join up."""
    xy, weld = np.unique(np.round(np.asarray(vertices)[:, :2], 6), axis=0, return_inverse=True)
    f = weld.reshape(-1)[np.asarray(faces, dtype=np.int64)]
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    b = edges[count == 1]
    return float(np.linalg.norm(xy[b[:, 0]] - xy[b[:, 1]], axis=1).sum())


def _signed_areas(tris: np.ndarray) -> np.ndarray:
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def _triangles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    return np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]


def rasterize_scene(scene, resolution: float = 0.2, kinds: Iterable[str] = DRIVABLE_KINDS,
                    pad_m: float = 1.0) -> GridMap:
    """Grid maps of a :class:`roadtwin_core.usd.TownScene` (see module docstring)."""
    if not (isinstance(resolution, (int, float)) and math.isfinite(resolution) and resolution > 0):
        raise RoadtwinError(f"grid resolution must be a positive number of metres, got {resolution}")
    kinds = tuple(kinds)
    roads = [r for r in scene.roads if r.kind in kinds and len(r.faces)]
    if not roads:
        found = sorted({r.kind for r in scene.roads}) or ["none"]
        raise RoadtwinError(f"{scene.source}: no road segments of kind {', '.join(kinds)} to plan on "
                            f"(found: {', '.join(found)})")
    origin, shape = _window(scene, roads, resolution, pad_m)
    n = shape[0] * shape[1]

    height = np.full(n, np.nan)
    road = np.zeros(n, bool)
    tris = np.concatenate([_triangles(r.vertices, r.faces) for r in roads])
    cells, _, z = rasterize_triangles(tris, origin, resolution, shape)
    road[cells] = True
    height[cells] = z

    road_names = {r.path.rsplit("/", 1)[-1] for r in roads}
    found = _DefectCells.of(scene.defects, road_names, origin, resolution, shape)
    defect = found.defect
    drivable = road | defect
    height[defect] = found.surface[defect]

    defect2 = defect.reshape(shape)
    index2 = found.index.reshape(shape)
    h2 = height.reshape(shape)
    depth = _defect_depths(index2, (road & ~defect).reshape(shape), h2, origin, resolution, found.depth_attr)
    return GridMap(origin, float(resolution), drivable.reshape(shape), defect2, depth,
                   h2.astype(np.float32), distance_field(defect2, resolution), index2, found.ids, found.types,
                   source=str(scene.source), name=scene.name, metadata=dict(scene.metadata))


def _window(scene, roads, resolution: float, pad_m: float) -> tuple[tuple[float, float], tuple[int, int]]:
    """Origin and (ny, nx) of the grid over the roads' bounding box, ``pad_m`` around it."""
    pts = np.concatenate([r.vertices[:, :2] for r in roads])
    # Cell centres sit a quarter cell off the resolution grid (0.05 + 0.2 k m at 0.2 m), so road
    # edges at round coordinates (multiples of 0.1 m) never pass exactly through a cell centre,
    # where "inside or not" would be decided by floating-point noise.
    lo = np.floor((pts.min(axis=0) - pad_m) / resolution) * resolution - resolution / 4
    hi = pts.max(axis=0) + pad_m
    nx, ny = (int(v) for v in np.ceil((hi - lo) / resolution))
    if nx * ny > MAX_CELLS:
        raise RoadtwinError(f"{scene.source}: a {resolution} m grid over {hi[0] - lo[0]:.0f} x {hi[1] - lo[1]:.0f} m "
                            f"needs {nx * ny / 1e6:.0f}M cells (limit {MAX_CELLS / 1e6:.0f}M); use a coarser resolution")
    return (float(lo[0]), float(lo[1])), (ny, nx)


@dataclass
class _DefectCells:
    """The defects lying on the lanes, as flat cell arrays: which cells, which defect, the
    defect surface height there, and per defect its id, type and stored depth attribute."""

    defect: np.ndarray                   # (n,) bool
    index: np.ndarray                    # (n,) int32, -1 outside defects
    surface: np.ndarray                  # (n,) float, NaN outside defects
    ids: list[str]
    types: list[str]
    depth_attr: list[float]

    @classmethod
    def of(cls, defects, road_names: set[str], origin: tuple[float, float], resolution: float,
           shape: tuple[int, int]) -> _DefectCells:
        n = shape[0] * shape[1]
        out = cls(np.zeros(n, bool), np.full(n, -1, np.int32), np.full(n, np.nan), [], [], [])
        for d in defects:
            pieces = [p for p in d.pieces if len(p.faces) and p.path.rsplit("/", 1)[-1] in road_names]
            if not pieces:
                continue  # a defect on a sidewalk (or with no baked geometry) is not on the lanes
            k = len(out.ids)
            out.ids.append(d.id)
            out.types.append(d.defect_type)
            out.depth_attr.append(float(d.attributes.get("depthM", 0.0) or 0.0))
            cells, z = _defect_cells(pieces, origin, resolution, shape)
            if len(cells) == 0:
                continue
            out.defect[cells] = True
            out.index[cells] = k
            out.surface[cells] = z
        return out


def _defect_cells(pieces, origin: tuple[float, float], resolution: float,
                  shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Flat cell indices of one defect and its surface height in each."""
    tris = np.concatenate([_triangles(p.vertices, p.faces) for p in pieces])
    cells, _, z = rasterize_triangles(tris, origin, resolution, shape)
    area = float(np.abs(_signed_areas(tris)).sum())
    perimeter = _boundary_length(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
    if 2 * area < resolution * perimeter:
        # Thinner than a cell on average (a crack): centre sampling would lose most of it, so
        # every cell one of its vertices falls in counts, at the height of its lowest vertex.
        ny, nx = shape
        v = np.concatenate([p.vertices for p in pieces])
        ix = np.floor((v[:, 0] - origin[0]) / resolution).astype(np.int64)
        iy = np.floor((v[:, 1] - origin[1]) / resolution).astype(np.int64)
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        vc = iy[ok] * nx + ix[ok]
        low = np.full(nx * ny, np.inf)
        np.minimum.at(low, vc, v[ok, 2])
        extra = np.setdiff1d(np.unique(vc), cells)
        cells, z = np.concatenate([cells, extra]), np.concatenate([z, low[extra]])
    return cells, z


def _defect_depths(index2: np.ndarray, road2: np.ndarray, h2: np.ndarray, origin: tuple[float, float],
                   resolution: float, depth_attr: list[float]) -> np.ndarray:
    """Depth: a plane fitted to the road cells in a ring around each defect, minus its surface."""
    ny, nx = index2.shape
    depth = np.zeros(index2.shape, np.float32)
    for k, box in enumerate(ndimage.find_objects(index2 + 1, max_label=len(depth_attr))):
        if box is None:
            continue
        r0, r1 = max(box[0].start - 4, 0), min(box[0].stop + 4, ny)
        c0, c1 = max(box[1].start - 4, 0), min(box[1].stop + 4, nx)
        sub = index2[r0:r1, c0:c1] == k
        road_sub = road2[r0:r1, c0:c1]
        ring = ndimage.binary_dilation(sub, iterations=2) & road_sub
        if ring.sum() < 3:
            ring = ndimage.binary_dilation(sub, iterations=4) & road_sub
        gy, gx = np.mgrid[r0:r1, c0:c1]
        sx = origin[0] + (gx + 0.5) * resolution
        sy = origin[1] + (gy + 0.5) * resolution
        sh = h2[r0:r1, c0:c1]
        if ring.sum() >= 3:
            A = np.column_stack([np.ones(ring.sum()), sx[ring], sy[ring]])
            coef, *_ = np.linalg.lstsq(A, sh[ring], rcond=None)
            base = coef[0] + coef[1] * sx[sub] + coef[2] * sy[sub]
        else:  # no road around it: fall back on the stored attribute
            base = sh[sub] + depth_attr[k]
        depth[r0:r1, c0:c1][sub] = (base - sh[sub]).astype(np.float32)
    return depth


def rasterize(stage, resolution: float = 0.2, kinds: Iterable[str] = DRIVABLE_KINDS) -> GridMap:
    """Grid maps of a composed town: a ``town.usda`` path, its directory, or a loaded TownScene."""
    if not isinstance(stage, TownScene):
        stage = Path(stage)
        if stage.is_dir():
            stage = stage / "town.usda"
        stage = load_town(stage)
    return rasterize_scene(stage, resolution, kinds)
