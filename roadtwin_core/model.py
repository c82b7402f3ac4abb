"""The data model: plain dataclasses over numpy arrays, no USD.

Conventions: meters, Z up. A road segment is planar in XY (its z is ignored; elevation comes
from a surface model). A defect model lives in a local frame centred on its footprint; its z is
*relative to the surrounding road* (negative below), and its boundary loop sits at z = 0: those
boundary heights are "pseudo-heights" that become the road surface height when merged.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import RoadtwinError
from .geometry import mesh_outline_polygon


def _as_vertices(a: Any, what: str) -> np.ndarray:
    v = np.ascontiguousarray(a, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] not in (2, 3):
        raise RoadtwinError(f"{what}: vertices must be (N,3), got shape {v.shape}")
    if v.shape[1] == 2:
        v = np.column_stack([v, np.zeros(len(v))])
    if not np.isfinite(v).all():
        raise RoadtwinError(f"{what}: vertices contain NaN or inf")
    return v


def _as_faces(a: Any, n_vertices: int, what: str) -> np.ndarray:
    f = np.ascontiguousarray(a, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= n_vertices):
        raise RoadtwinError(f"{what}: face indices out of range 0..{n_vertices - 1}")
    return f


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed XY areas of triangles (positive when counter-clockwise seen from +Z)."""
    a, b, c = (vertices[faces[:, i], :2] for i in range(3))
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def polygon_area(loop_xy: np.ndarray) -> float:
    """Signed shoelace area of a closed loop given without repeating the first point."""
    x, y = loop_xy[:, 0], loop_xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


@dataclass(frozen=True)
class DefectLook:
    """A defect's own surface texture (e.g. cut from a photo): texture files by role
    (``diffuse`` sRGB RGBA, ``roughness``, ``normal``; absolute paths) and the affine map from the
    model's local XY (metres) to texture st: ``st = st_from_local @ [x, y, 1]``. An affine map,
    not per-vertex st, so the look survives remeshing and merging: any piece of the defect gets
    its st from where it lies (a decal over the defect's footprint)."""

    textures: dict[str, str]
    st_from_local: tuple[tuple[float, float, float], tuple[float, float, float]]

    def st(self, local_xy: np.ndarray) -> np.ndarray:
        a = np.asarray(self.st_from_local, dtype=np.float64)
        return np.asarray(local_xy, dtype=np.float64)[:, :2] @ a[:, :2].T + a[:, 2]

    @classmethod
    def fit(cls, textures: dict[str, str], local_xy: np.ndarray, st: np.ndarray,
            tolerance: float = 1e-4) -> "DefectLook | None":
        """The look whose affine map reproduces per-vertex ``st`` (least squares); None when st
        is not affine in XY within ``tolerance`` (st units): such a texture is no decal."""
        xy = np.asarray(local_xy, dtype=np.float64)[:, :2]
        st = np.asarray(st, dtype=np.float64).reshape(-1, 2)
        design = np.column_stack([xy, np.ones(len(xy))])
        affine, *_ = np.linalg.lstsq(design, st, rcond=None)
        if len(xy) < 3 or np.abs(design @ affine - st).max() > tolerance:
            return None
        return cls(dict(textures), tuple(tuple(float(x) for x in row) for row in affine.T))


@dataclass
class DefectModel:
    """A 2.5D defect surface in its local frame (see module docstring)."""

    name: str
    defect_type: str
    vertices: np.ndarray
    faces: np.ndarray
    boundary: np.ndarray
    pseudo_height: np.ndarray | None = None
    source: str = "parametric"
    params: dict[str, Any] = field(default_factory=dict)
    look: DefectLook | None = None           # its own texture; None: the type's material

    def __post_init__(self) -> None:
        what = f"defect model {self.name!r}"
        self.vertices = _as_vertices(self.vertices, what)
        self.faces = _as_faces(self.faces, len(self.vertices), what)
        self.boundary = np.ascontiguousarray(self.boundary, dtype=np.int64)
        if len(self.boundary) < 3:
            raise RoadtwinError(f"{what}: boundary loop needs at least 3 vertices")
        if polygon_area(self.vertices[self.boundary, :2]) < 0:
            self.boundary = self.boundary[::-1].copy()
        if self.pseudo_height is None:
            flags = np.zeros(len(self.vertices), dtype=bool)
            flags[self.boundary] = True
            self.pseudo_height = flags
        self.pseudo_height = np.asarray(self.pseudo_height, dtype=bool)
        self.vertices[self.pseudo_height, 2] = 0.0
        if len(self.faces) == 0:
            raise RoadtwinError(f"{what}: has no faces")
        areas = triangle_areas(self.vertices, self.faces)
        if (areas <= 0).any():
            raise RoadtwinError(f"{what}: {int((areas <= 0).sum())} faces are degenerate or folded over in XY")

    @property
    def footprint(self) -> np.ndarray:
        """Boundary loop in XY, counter-clockwise."""
        return self.vertices[self.boundary, :2]

    @property
    def area_m2(self) -> float:
        return float(triangle_areas(self.vertices, self.faces).sum())

    @property
    def signed_volume_m3(self) -> float:
        """Exact integral of z over the footprint for the piecewise-linear surface."""
        z = self.vertices[self.faces, 2].mean(axis=1)
        return float((triangle_areas(self.vertices, self.faces) * z).sum())

    @property
    def volume_m3(self) -> float:
        """Volume between the defect surface and the road plane (missing or added material)."""
        return abs(self.signed_volume_m3)

    @property
    def depth_m(self) -> float:
        """Deepest point below the road (0 for a pure bump)."""
        return float(max(0.0, -self.vertices[:, 2].min()))

    @property
    def height_m(self) -> float:
        """Highest point above the road (0 for a pure depression)."""
        return float(max(0.0, self.vertices[:, 2].max()))

    def measures(self) -> tuple[float, float, float, float]:
        """(depth_m, height_m, area_m2, volume_m3), computed once per vertex/face arrays: a
        town's thousand placements share a few dozen models, and each placement reports them."""
        memo = self.__dict__.get("_measures")
        if memo is None or memo[0] is not self.vertices or memo[1] is not self.faces:
            memo = (self.vertices, self.faces, (self.depth_m, self.height_m, self.area_m2, self.volume_m3))
            self.__dict__["_measures"] = memo
        return memo[2]

    def attributes(self) -> dict[str, Any]:
        depth, height, area, volume = self.measures()
        return {"type": self.defect_type, "depthM": depth, "heightM": height,
                "areaM2": area, "volumeM3": volume, "source": self.source}


@dataclass
class RoadSegment:
    """A planar road mesh with a semantic kind (driving, sidewalk, shoulder, junction ...)."""

    id: str
    kind: str
    vertices: np.ndarray
    faces: np.ndarray
    centerline: np.ndarray | None = None
    attributes: dict[str, Any] = field(default_factory=dict)
    prim_path: str = ""
    _polygon: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        what = f"road segment {self.id!r}"
        self.vertices = _as_vertices(self.vertices, what)
        self.vertices[:, 2] = 0.0
        self.faces = _as_faces(self.faces, len(self.vertices), what)
        if len(self.faces) == 0:
            raise RoadtwinError(f"{what}: has no faces")
        if self.centerline is not None:
            self.centerline = np.asarray(self.centerline, dtype=np.float64).reshape(-1, 2)

    def polygon(self):
        """The segment's outline as a shapely polygon (non-convex and holes allowed); computed once."""
        if self._polygon is None:
            self._polygon = mesh_outline_polygon(self.vertices, self.faces, f"road segment {self.id!r}")
        return self._polygon

    def travel_direction(self, xy: np.ndarray) -> np.ndarray:
        """Unit travel direction at points, from the centerline (or the outline's long axis)."""
        xy = np.atleast_2d(xy)
        if self.centerline is not None and len(self.centerline) >= 2:
            c = self.centerline
            seg = c[1:] - c[:-1]
            mid = 0.5 * (c[1:] + c[:-1])
            idx = np.argmin(((xy[:, None, :] - mid[None]) ** 2).sum(-1), axis=1)
            d = seg[idx]
        else:
            pts = self.vertices[:, :2] - self.vertices[:, :2].mean(0)
            _, _, vt = np.linalg.svd(pts, full_matrices=False)
            d = np.repeat(vt[:1], len(xy), axis=0)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass
class Placement:
    """One defect instance: which model, where, how big. Segments are filled by placement."""

    instance_id: str
    model: DefectModel
    x: float
    y: float
    yaw: float
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    segment_ids: tuple[str, ...] = ()

    def transform_xy(self, local_xy: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        sx, sy, _ = self.scale
        x = local_xy[:, 0] * sx
        y = local_xy[:, 1] * sy
        return np.column_stack([c * x - s * y + self.x, s * x + c * y + self.y])

    def world_vertices(self) -> np.ndarray:
        """Vertices with world XY and z still relative to the road surface."""
        v = self.model.vertices
        return np.column_stack([self.transform_xy(v[:, :2]), v[:, 2] * self.scale[2]])

    def world_footprint(self) -> np.ndarray:
        return self.transform_xy(self.model.footprint)

    def local_xy(self, world_xy: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`transform_xy`: world XY back into the model's frame."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        sx, sy, _ = self.scale
        d = np.asarray(world_xy, dtype=np.float64)[:, :2] - (self.x, self.y)
        return np.column_stack([(c * d[:, 0] + s * d[:, 1]) / sx, (-s * d[:, 0] + c * d[:, 1]) / sy])

    def attributes(self) -> dict[str, Any]:
        sx, sy, sz = self.scale
        m = self.model
        depth, height, area, volume = m.measures()
        return {"type": m.defect_type, "depthM": depth * sz, "heightM": height * sz,
                "areaM2": area * sx * sy, "volumeM3": volume * sx * sy * sz,
                "source": m.source, "model": m.name}


@dataclass
class ComposeRules:
    """How to populate a layout with defects; stored on the layout's root prim."""

    defect_count: int = 40
    type_weights: dict[str, float] = field(default_factory=lambda: {
        "pothole": 4.0, "depression": 1.0, "bump": 0.5, "rut": 1.0, "manhole": 0.5, "crack": 2.0, "patch": 1.0})
    seed: int = 0
    surface: str = "flat"
    merger: str = "cdt"
    kinds: tuple[str, ...] = ("driving",)
    models_per_type: int = 4
    scale_range: tuple[float, float] = (0.8, 1.2)
    edge_margin_m: float = 0.3
    spacing_m: float = 0.4
    road_edge_m: float = 0.5
    wheel_path_weight: float = 2.0   # defect density in wheel paths relative to the rest of a lane
    density_per_km: float = 0.0      # > 0: defect count = density x km of lane centerline
    library: str = ""                # folder of defect assets (e.g. reconstructed) drawn with the parametric ones

    def replace(self, **changes: Any) -> "ComposeRules":
        changes = {k: v for k, v in changes.items() if v is not None}
        return dataclasses.replace(self, **changes)

    def check(self, owner: str) -> "ComposeRules":
        if self.defect_count < 0:
            raise RoadtwinError(f"{owner}: defect count must be >= 0, got {self.defect_count}")
        if self.seed < 0:  # numpy's SeedSequence refuses negative seeds
            raise RoadtwinError(f"{owner}: seed must be >= 0, got {self.seed}")
        if self.models_per_type < 1:
            raise RoadtwinError(f"{owner}: models per type must be >= 1, got {self.models_per_type}")
        for name in ("edge_margin_m", "spacing_m", "road_edge_m", "wheel_path_weight", "density_per_km"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0 or (name == "road_edge_m" and v <= 0):
                raise RoadtwinError(f"{owner}: rule {name} must be a positive finite number, got {v}")
        lo, hi = self.scale_range
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise RoadtwinError(f"{owner}: scale range must satisfy 0 < lo <= hi, got {self.scale_range}")
        for k, w in self.type_weights.items():
            if not math.isfinite(w) or w < 0:
                raise RoadtwinError(f"{owner}: weight of defect type {k!r} must be >= 0, got {w}")
        if self.defect_count and sum(self.type_weights.values()) <= 0:
            raise RoadtwinError(f"{owner}: all defect type weights are zero")
        return self


@dataclass
class FixedDefect:
    """A defect the layout pins in place (a test scenario, a surveyed defect): generated from its
    type and parameters with its own seed, then placed exactly at (x, y, yaw, scale)."""

    name: str
    defect_type: str
    params: dict[str, Any]
    x: float
    y: float
    yaw: float = 0.0
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    seed: int = 0


# OpenDRIVE roadMark types (spaces become underscores); "curb" is a kerb, not paint, and is
# kept as data but draws no paint.
MARKING_TYPES = ("solid", "broken", "solid_solid", "solid_broken", "broken_solid", "broken_broken",
                 "botts_dots", "curb")
PAINTED_MARKING_TYPES = MARKING_TYPES[:-1]


@dataclass
class LaneMarking:
    """A painted line (or pair of lines) along a lane boundary, as data in the layout.

    ``points`` is the boundary polyline in XY (travel order of the lane section it came from).
    A broken line paints ``dash_m`` then leaves ``gap_m`` bare, starting ``phase_m`` along the
    polyline; ``dash_m == 0`` means continuous. Double types (``solid_broken`` ...) are two lines
    ``spacing_m`` apart centre to centre, the first word on the left of travel. Botts dots are
    round dots ``width_m`` across every ``dash_m + gap_m``. Widths in metres.
    """

    id: str
    marking_type: str
    color: str
    width_m: float
    points: np.ndarray
    dash_m: float = 0.0
    gap_m: float = 0.0
    phase_m: float = 0.0
    spacing_m: float = 0.0

    def __post_init__(self) -> None:
        what = f"lane marking {self.id!r}"
        if self.marking_type not in MARKING_TYPES:
            raise RoadtwinError(f"{what}: unknown type {self.marking_type!r} (known: {', '.join(MARKING_TYPES)})")
        self.points = _as_vertices(self.points, what)[:, :2].copy()
        if len(self.points) < 2:
            raise RoadtwinError(f"{what}: needs at least 2 points")
        for name in ("width_m", "dash_m", "gap_m", "phase_m", "spacing_m"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise RoadtwinError(f"{what}: {name} must be a finite number >= 0, got {v}")
            setattr(self, name, v)
        if self.width_m <= 0:
            raise RoadtwinError(f"{what}: width_m must be > 0")
        if self.dash_m > 0 and self.gap_m <= 0:
            raise RoadtwinError(f"{what}: a broken line needs gap_m > 0")

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def lines(self) -> list[tuple[float, float, float]]:
        """(lateral offset to the left of travel, dash, gap) of each painted line; dash 0 = solid."""
        parts = self.marking_type.split("_")
        if self.marking_type == "curb":
            return []
        if self.marking_type == "botts_dots":
            return [(0.0, self.dash_m, self.gap_m)]
        pattern = {"solid": (0.0, 0.0), "broken": (self.dash_m, self.gap_m)}
        if len(parts) == 1:
            return [(0.0, *pattern[parts[0]])]
        half = self.spacing_m / 2
        return [(half, *pattern[parts[0]]), (-half, *pattern[parts[1]])]


@dataclass
class MapObject:
    """A thing a map places beside (or on) its roads: an OpenDRIVE ``<object>`` or ``<signal>``.

    ``kind`` "object" or "signal"; ``type``/``subtype`` as the map writes them (OpenDRIVE object
    types: pole, tree, vegetation, barrier, car ...; a signal's country code type); ``position``
    world (x, y, z), z = road elevation + the map's zOffset; ``hpr`` world heading, pitch, roll
    (rad) of the object's +X (a signal: the direction its face looks); ``size`` (length, width,
    height) in metres, 0 where the map gives none; ``dynamic``: a signal that changes (a traffic
    light). Compose turns them into props (docs/architecture.md, USD conventions).
    """

    id: str
    kind: str
    type: str
    position: tuple[float, float, float]
    hpr: tuple[float, float, float] = (0.0, 0.0, 0.0)
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    subtype: str = ""
    name: str = ""
    road: str = ""
    dynamic: bool = False


@dataclass
class TownLayout:
    """Road segments plus the composition rules and where they came from.

    ``terrain`` holds optional (N,3) world elevation samples (the k-d tree elevation source),
    ``fixed`` the defects the layout pins in place, ``markings`` the painted lane markings,
    ``objects`` the map's roadside objects and signs (:class:`MapObject`),
    ``metadata`` free-form strings carried to the
    town stage (geo-reference, attribution, default route ...).
    """

    name: str
    segments: list[RoadSegment]
    rules: ComposeRules = field(default_factory=ComposeRules)
    source: str = ""
    terrain: np.ndarray | None = None
    fixed: list[FixedDefect] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)
    markings: list[LaneMarking] = field(default_factory=list)
    objects: list[MapObject] = field(default_factory=list)

    def segment(self, segment_id: str) -> RoadSegment:
        for s in self.segments:
            if s.id == segment_id:
                return s
        raise RoadtwinError(f"{self.source or self.name}: no road segment {segment_id!r}")


@dataclass
class MergedSegment:
    """A merger's output for one segment: one mesh, each face owned by the road or a defect.

    ``face_owner[i] == -1`` marks road faces; otherwise the index into the placements given
    to the merger. Vertices carry the restored elevation. Road and defect faces share the
    seam vertices, so splitting by owner never opens a gap.
    """

    segment_id: str
    vertices: np.ndarray
    faces: np.ndarray
    face_owner: np.ndarray
    ring_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def part(self, owner: int) -> tuple[np.ndarray, np.ndarray]:
        """Compact vertices/faces of the faces owned by ``owner``."""
        f = self.faces[self.face_owner == owner]
        used, inverse = np.unique(f, return_inverse=True)
        return self.vertices[used], inverse.reshape(-1, 3).astype(np.int64)
