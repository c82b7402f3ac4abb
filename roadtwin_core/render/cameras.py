"""Camera models and camera poses: pinhole intrinsics, mono and rectified stereo cameras, random
poses along lane centerlines and continuous drives at a given speed. numpy only.

Conventions (also written to ``meta.json``):

- world: Z up, metres (the town's frame);
- camera: OpenCV, x right, y down, z forward; ``cam_to_world`` is the 4x4 matrix that maps camera
  coordinates to world coordinates (its columns are the camera axes and centre in the world);
- pixels: ``u = fx * X / Z + cx``, ``v = fy * Y / Z + cy`` with pixel centres at integer
  coordinates (OpenCV), so the default principal point is ``((W - 1) / 2, (H - 1) / 2)``;
- stereo: a rectified rig, the right camera is the left one moved ``baseline`` metres along the
  left camera's x axis, same intrinsics; left disparity ``d = fx * B / Z`` (right pixel = u - d);
- yaw: rotation about world Z, 0 = looking along +X, counter-clockwise positive; pitch: positive
  looks up; roll: rotation about the optical axis (camera x towards camera y).
"""
from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import RoadtwinError


def pixel_grid(k: "Intrinsics") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Read-only float64 (H, W) grids of an image: u, v (pixel columns, rows) and the normalized
    image coordinates (u - cx) / fx, (v - cy) / fy. Cached: every frame of a render asks."""
    return _pixel_grid(k.width, k.height, k.fx, k.fy, k.cx, k.cy)


@functools.lru_cache(maxsize=8)
def _pixel_grid(width, height, fx, fy, cx, cy):
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    grids = (u, v, (u - cx) / fx, (v - cy) / fy)
    for g in grids:
        g.flags.writeable = False
    return grids


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float = 90.0) -> "Intrinsics":
        if width <= 0 or height <= 0:
            raise RoadtwinError(f"image size must be positive, got {width}x{height}")
        if not 1.0 <= hfov_deg <= 179.0:
            raise RoadtwinError(f"horizontal field of view must be in [1, 179] degrees, got {hfov_deg}")
        f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
        return cls(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def as_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx,
                "cy": self.cy, "K": self.K.tolist()}


def camera_matrix(k, what: str = "K") -> np.ndarray:
    """A 3x3 camera matrix from fx, fy, cx, cy or its 9 entries (a calibration file's or a
    reconstructor input's ``K``): one line naming ``what`` when it is neither, or not finite, or a
    focal length is not positive."""
    try:
        a = np.asarray(k, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise RoadtwinError(f"{what}: expected fx, fy, cx, cy or a 3x3 matrix, got {k!r}") from None
    if a.size == 4:
        fx, fy, cx, cy = a
        a = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0])
    if a.size != 9 or not np.isfinite(a).all() or a[0] <= 0 or a[4] <= 0:
        raise RoadtwinError(f"{what}: expected fx, fy, cx, cy (or 3x3) with positive focal lengths, got {k!r}")
    return a.reshape(3, 3)


def rotation_ypr(yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """Camera-to-world rotation (columns x right, y down, z forward) from angles in radians."""
    f = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
    r = np.array([math.sin(yaw), -math.cos(yaw), 0.0])          # horizontal right of the heading
    d = np.cross(f, r)                                          # image down
    c, s = math.cos(roll), math.sin(roll)
    r, d = c * r + s * d, -s * r + c * d
    return np.column_stack([r, d, f])


def look_from(position, yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """4x4 cam_to_world for a camera at ``position`` with yaw/pitch/roll in radians."""
    m = np.eye(4)
    m[:3, :3] = rotation_ypr(yaw, pitch, roll)
    m[:3, 3] = np.asarray(position, dtype=np.float64)
    return m


_EYE3 = np.eye(3)
_ORTHONORMAL_TOL = 1e-4 + 1e-5 * _EYE3      # np.allclose(r.T @ r, I, atol=1e-4), without its 40 us a call


@dataclass
class Camera:
    """A pinhole camera: intrinsics and a 4x4 camera-to-world pose."""

    intrinsics: Intrinsics
    cam_to_world: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.cam_to_world, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise RoadtwinError(f"camera pose must be a finite 4x4 matrix, got shape {m.shape}")
        r = m[:3, :3]
        if not (np.abs(r.T @ r - _EYE3) <= _ORTHONORMAL_TOL).all() or np.linalg.det(r) < 0:
            raise RoadtwinError("camera pose rotation is not a proper rotation (orthonormal, det +1)")
        self.cam_to_world = m

    @property
    def position(self) -> np.ndarray:
        return self.cam_to_world[:3, 3]

    @property
    def rotation(self) -> np.ndarray:
        return self.cam_to_world[:3, :3]

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - self.position) @ self.rotation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points -> pixel coordinates (N,2) and z-depth (N,) (points behind: z <= 0)."""
        pc = self.world_to_camera(points)
        k = self.intrinsics
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.column_stack([k.fx * pc[:, 0] / z + k.cx, k.fy * pc[:, 1] / z + k.cy])
        return uv, z

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit world ray directions (H, W, 3) and the camera centre."""
        k = self.intrinsics
        u, v = np.meshgrid(np.arange(k.width, dtype=np.float64), np.arange(k.height, dtype=np.float64))
        dc = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], axis=-1)
        d = dc @ self.rotation.T
        return d / np.linalg.norm(d, axis=-1, keepdims=True), self.position.copy()


@dataclass
class StereoCamera:
    """A rectified stereo rig: ``left`` and the same camera ``baseline`` m along its x axis."""

    left: Camera
    baseline: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.baseline) and self.baseline > 0):
            raise RoadtwinError(f"stereo baseline must be > 0 m, got {self.baseline}")

    @property
    def intrinsics(self) -> Intrinsics:
        return self.left.intrinsics

    @property
    def cam_to_world(self) -> np.ndarray:
        return self.left.cam_to_world

    @property
    def right(self) -> Camera:
        m = self.left.cam_to_world.copy()
        m[:3, 3] += self.baseline * m[:3, 0]
        return Camera(self.left.intrinsics, m)


# ------------------------------------------------------------------------------------- poses
@dataclass
class Lane:
    """A lane centerline in travel order (XY polyline) and its id."""

    id: str
    points: np.ndarray

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 2)
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-9])
        self.points = self.points[keep]
        self.cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.points, axis=0), axis=1))])

    @property
    def length(self) -> float:
        return float(self.cum[-1])

    def at(self, s: np.ndarray) -> np.ndarray:
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self.length)
        return np.column_stack([np.interp(s, self.cum, self.points[:, 0]), np.interp(s, self.cum, self.points[:, 1])])

    def heading(self, s: np.ndarray, window: float = 1.0) -> np.ndarray:
        """Travel heading (radians) at arc lengths ``s``, from the chord over +-``window`` m
        (smooth across polyline corners)."""
        s = np.asarray(s, dtype=np.float64)
        d = self.at(s + window) - self.at(s - window)
        return np.arctan2(d[:, 1], d[:, 0])


GroundFn = Callable[[np.ndarray], np.ndarray]


def _usable(lanes: Sequence[Lane], min_length: float = 0.0) -> list[Lane]:
    return [l for l in lanes if len(l.points) >= 2 and l.length > max(min_length, 1e-6)]


def vehicle_height(ground: GroundFn, xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Road height under a car-mounted camera: mean of the ground at the camera and at four
    wheel-like points (+-1.3 m along, +-0.8 m across the heading), so a small pothole under the
    camera does not drop it; NaN where no sample lies on the road."""
    xy = np.atleast_2d(xy)
    c, s = np.cos(heading), np.sin(heading)
    offsets = [(0.0, 0.0), (1.3, 0.8), (1.3, -0.8), (-1.3, 0.8), (-1.3, -0.8)]
    zs = [ground(np.column_stack([xy[:, 0] + a * c - b * s, xy[:, 1] + a * s + b * c])) for a, b in offsets]
    z = np.stack(zs)
    ok = np.isfinite(z)
    count = ok.sum(axis=0)
    total = np.where(ok, z, 0.0).sum(axis=0)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


@dataclass(frozen=True)
class KeepOut:
    """Plan discs cameras stay out of: things standing in the lanes (a stopped car), each
    ``xy`` (N,2) with the radius that holds it (N,), grown by ``margin_m``."""

    xy: np.ndarray
    radius: np.ndarray
    margin_m: float = 3.5

    def clear(self, xy: np.ndarray) -> bool:
        """Whether the plan point ``xy`` lies outside every disc."""
        if not len(self.xy):
            return True
        d2 = ((self.xy - np.asarray(xy, np.float64)[:2]) ** 2).sum(axis=1)
        return bool((d2 >= (self.radius + self.margin_m) ** 2).all())


NO_KEEP_OUT = KeepOut(np.zeros((0, 2)), np.zeros(0))


def lane_keep_out(town, margin_m: float = 3.5) -> KeepOut:
    """The props a composed town stands in its driving lanes (``TownScene.instances`` of
    instancers placed ``lane``: stopped vehicles) as a :class:`KeepOut`: a survey camera on or
    just behind one would sit inside or against a car."""
    held = [inst for inst in getattr(town, "instances", ()) if inst.place == "lane" and len(inst.positions)]
    if not held:
        return NO_KEEP_OUT
    return KeepOut(np.concatenate([np.asarray(i.positions, np.float64)[:, :2] for i in held]),
                   np.concatenate([np.asarray(i.radii, np.float64) for i in held]), margin_m)


def sample_lane_poses(lanes: Sequence[Lane], n: int, rng: np.random.Generator, ground: GroundFn, *,
                      height: float = 1.5, yaw_jitter_deg: float = 20.0, pitch_deg: tuple = (-30.0, -5.0),
                      roll_jitter_deg: float = 2.0, lateral_jitter_m: float = 0.4,
                      keep_out: KeepOut = NO_KEEP_OUT) -> list[np.ndarray]:
    """``n`` random cam_to_world poses on lanes: a point uniform in arc length over all lanes,
    shifted sideways a little, ``height`` m above the road, looking down the lane with random
    yaw / pitch / roll jitter (random poses reduce view bias, as in the paper); never inside
    ``keep_out`` (vehicles standing in the lanes)."""
    usable = _usable(lanes)
    if not usable:
        raise RoadtwinError("no lane centerline to place cameras on")
    lengths = np.array([l.length for l in usable])
    poses = []
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 50 * n + 100:
            raise RoadtwinError(f"could not place {n} cameras on the road: the lanes' ground is missing "
                                f"under their centerlines, or vehicles stand there (placed {len(poses)})")
        lane = usable[rng.choice(len(usable), p=lengths / lengths.sum())]
        s = rng.uniform(0.0, lane.length)
        heading = float(lane.heading(np.array([s]))[0])
        xy = lane.at(np.array([s]))[0]
        side = rng.uniform(-lateral_jitter_m, lateral_jitter_m)
        xy = xy + side * np.array([-math.sin(heading), math.cos(heading)])
        if not keep_out.clear(xy):
            continue
        z = vehicle_height(ground, xy[None], np.array([heading]))[0]
        if not np.isfinite(z):
            continue
        yaw = heading + math.radians(rng.uniform(-yaw_jitter_deg, yaw_jitter_deg))
        pitch = math.radians(rng.uniform(*pitch_deg))
        roll = math.radians(rng.uniform(-roll_jitter_deg, roll_jitter_deg))
        poses.append(look_from((xy[0], xy[1], z + height), yaw, pitch, roll))
    return poses


def lane_trajectory(lanes: Sequence[Lane], rng: np.random.Generator, ground: GroundFn, *, speed: float,
                    rate_hz: float, n_frames: int, height: float = 1.5, pitch_deg: float = -15.0
                    ) -> tuple[np.ndarray, list[np.ndarray]]:
    """A continuous drive along one lane at ``speed`` m/s sampled at ``rate_hz``: frame times (s)
    and cam_to_world poses. The lane is drawn at random among those long enough."""
    if not (speed >= 0 and math.isfinite(speed)):
        raise RoadtwinError(f"speed must be a finite number >= 0 m/s, got {speed}")
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise RoadtwinError(f"frame rate must be > 0 Hz, got {rate_hz}")
    if n_frames < 2:
        raise RoadtwinError(f"a trajectory needs at least 2 frames, got {n_frames}")
    times = np.arange(n_frames) / rate_hz
    travel = speed * times[-1]
    usable = _usable(lanes, travel)
    if not usable:
        longest = max((l.length for l in lanes), default=0.0)
        raise RoadtwinError(f"no lane is long enough for {n_frames} frames at {speed} m/s and {rate_hz} Hz "
                            f"({travel:.1f} m; the longest lane is {longest:.1f} m)")
    lane = usable[rng.integers(len(usable))]
    s0 = rng.uniform(0.0, lane.length - travel)
    s = s0 + speed * times
    xy = lane.at(s)
    heading = lane.heading(s, window=2.0)
    z = vehicle_height(ground, xy, heading)
    if not np.isfinite(z).all():
        raise RoadtwinError(f"lane {lane.id}: the road is missing under part of the trajectory")
    poses = [look_from((x, y, zz + height), h, math.radians(pitch_deg)) for (x, y), zz, h in zip(xy, z, heading)]
    return times, poses


def load_poses_file(path: str | Path) -> list[np.ndarray]:
    """cam_to_world poses from JSON: a list (or ``{"poses": [...]}``, or a previous render's
    ``meta.json`` with ``{"frames": [...]}``) of items with either ``cam_to_world`` (4x4,
    OpenCV camera axes) or ``position`` [x, y, z] plus ``yaw_deg``, ``pitch_deg``, ``roll_deg``."""
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such poses file")
    if not path.is_file():
        raise RoadtwinError(f"{path}: is not a file (expected a JSON poses file)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError, OSError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RoadtwinError(f"{path}: not a JSON poses file ({first})") from None
    items = data.get("poses", data.get("frames")) if isinstance(data, dict) else data
    if not isinstance(items, list) or not items:
        raise RoadtwinError(f"{path}: no poses (expected a non-empty list, or {{\"poses\": [...]}})")
    poses = []
    for k, item in enumerate(items):
        try:
            if not isinstance(item, dict):
                raise TypeError(f"got {type(item).__name__}")
            if "cam_to_world" in item:
                m = np.asarray(item["cam_to_world"], dtype=np.float64)
            else:
                pos = np.asarray(item["position"], dtype=np.float64)
                if pos.shape != (3,):
                    raise ValueError(f"position must be [x, y, z], got {item['position']!r}")
                angles = [float(item.get(key, 0.0)) for key in ("yaw_deg", "pitch_deg", "roll_deg")]
                if not np.isfinite(angles).all():
                    raise ValueError(f"angles must be finite, got {angles}")
                m = look_from(pos, *map(math.radians, angles))
        except (TypeError, KeyError, ValueError) as exc:
            raise RoadtwinError(f"{path}: pose {k}: needs cam_to_world or position (+ yaw_deg, pitch_deg) ({exc})") from None
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise RoadtwinError(f"{path}: pose {k}: cam_to_world must be a finite 4x4 matrix")
        r = m[:3, :3]
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0 or not np.allclose(m[3], [0, 0, 0, 1]):
            raise RoadtwinError(f"{path}: pose {k}: cam_to_world is not a rigid transform (rotation orthonormal, det +1)")
        if np.abs(m[:3, 3]).max() > MAX_COORD_M:
            raise RoadtwinError(f"{path}: pose {k}: position {m[:3, 3].tolist()} is absurdly far (beyond {MAX_COORD_M:g} m)")
        poses.append(m)
    return poses


MAX_COORD_M = 1e7  # a camera farther than 10,000 km from the origin is a corrupt file


# ------------------------------------------------------------------------------ rig presets
@dataclass(frozen=True)
class RigPreset:
    """A named camera rig: image size, horizontal field of view, mounting height above the road
    and pitch (cameras' convention: negative looks down), and a stereo baseline (None = mono).
    ``source`` says where the numbers come from."""

    name: str
    width: int
    height: int
    hfov_deg: float
    height_m: float
    pitch_deg: float
    baseline_m: float | None = None
    source: str = ""

    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_fov(self.width, self.height, self.hfov_deg)


RIG_PRESETS: dict[str, RigPreset] = {p.name: p for p in (
    # Estimated from the road_defects_br train frames' ego-lane labels (bench/estimate_survey_rig.py,
    # docs/survey_rig.md): horizon 48 px above the top row (IQR 45-52), lane width growing 1.36 px
    # per row; with a 3.5 m lane and an assumed 60 deg field of view (not observable from lane
    # lines alone): 2.33 m high (IQR 2.27-2.41), pitched 25.1 deg down (IQR 24.8-25.5).
    RigPreset("survey", 512, 320, 60.0, 2.33, -25.1, None,
              "estimated from road_defects_br lane labels; field of view assumed"),
    # A windscreen dashcam: wide lens as a pinhole, car roof-line height, slightly down.
    RigPreset("dashcam", 960, 540, 90.0, 1.3, -5.0, None, "nominal"),
    # KITTI's colour stereo pair: 0.54 m baseline, 1.65 m above the road, level; fx 721.5 px at
    # 1242x375 (its rectified calibration) -> 81.4 deg.
    RigPreset("stereo", 1242, 375, 81.4, 1.65, 0.0, 0.54, "KITTI (Geiger et al. 2013) sensor setup"),
    # Looking down at the pavement with a ZED-class stereo camera (0.12 m baseline, about 90 deg),
    # as in Fan et al.'s stereo pothole frames; height and pitch nominal.
    RigPreset("inspection", 855, 514, 90.0, 1.0, -60.0, 0.12, "nominal (ZED baseline)"),
)}
