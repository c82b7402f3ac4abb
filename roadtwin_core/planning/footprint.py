"""The vehicle as planning sees it: a footprint (wheels, tire patches, body rectangle, steering).

Built from the one vehicle description, :class:`roadtwin_core.vehicle.VehicleParams`, by
``VehicleParams.footprint()``; planning never keeps vehicle numbers of its own, so a path
planned for a car and that car's vibration sweep describe the same car.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from ..errors import RoadtwinError

WHEEL_NAMES = ("rear-left", "rear-right", "front-left", "front-right")
_INSET = 1e-4  # footprint sample points sit this far inside the rectangle edges


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class Footprint:
    """What planning needs of a vehicle (``VehicleParams.footprint()`` builds it).

    The pose is the rear-axle centre. ``track_m`` is wheel centre to wheel centre,
    ``tire_length_m`` the tire's contact patch length. The body rectangle runs from
    ``rear_overhang_m`` behind the rear axle to ``body_length_m`` ahead of that; it is at least
    as wide as the outer tire edges (track + tire width), so a body-level check always includes
    the wheel-level one. The paper's car (2.0 m track, 3.0 m wheelbase) is the shipped vehicle
    file ``roadtwin_core/vehicle/paper_car.toml``.
    """

    track_m: float
    wheelbase_m: float
    tire_width_m: float
    tire_length_m: float
    body_length_m: float
    body_width_m: float
    rear_overhang_m: float
    max_steer_rad: float

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if not (math.isfinite(v) and v > 0):
                raise RoadtwinError(f"vehicle: {k} must be a positive finite number, got {v}")
        if self.tire_width_m >= self.track_m:
            raise RoadtwinError("vehicle: tire_width_m must be smaller than track_m")
        if self.body_length_m < self.wheelbase_m + self.rear_overhang_m:
            raise RoadtwinError("vehicle: body_length_m must cover rear overhang + wheelbase")
        if self.max_steer_rad >= math.pi / 2:
            raise RoadtwinError("vehicle: max_steer_rad must be < pi/2")

    @property
    def min_turn_radius_m(self) -> float:
        """Rear-axle turning radius of the kinematic bicycle at full lock."""
        return self.wheelbase_m / math.tan(self.max_steer_rad)

    @property
    def straddle_gap_m(self) -> float:
        """Free width between the inner tire edges (what a defect must be narrower than)."""
        return self.track_m - self.tire_width_m

    def wheel_offsets(self) -> np.ndarray:
        """(4, 2) wheel contact centres in the vehicle frame, in ``WHEEL_NAMES`` order."""
        h, L = self.track_m / 2, self.wheelbase_m
        return np.array([[0.0, h], [0.0, -h], [L, h], [L, -h]])

    def tire_points(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Sample points of the four tire patches (K, 2) and the wheel index of each (K,)."""
        a = _axis(self.tire_length_m, spacing)
        b = _axis(self.tire_width_m, spacing)
        patch = np.stack(np.meshgrid(a, b, indexing="ij"), axis=-1).reshape(-1, 2)
        pts = (self.wheel_offsets()[:, None, :] + patch[None]).reshape(-1, 2)
        return pts, np.repeat(np.arange(4), len(patch))

    def body_rect(self) -> tuple[float, float, float, float]:
        w = max(self.body_width_m, self.track_m + self.tire_width_m) / 2
        return -self.rear_overhang_m, self.body_length_m - self.rear_overhang_m, -w, w

    def body_points(self, spacing: float, outline_only: bool) -> np.ndarray:
        x0, x1, y0, y1 = self.body_rect()
        xs = _axis(x1 - x0, spacing) + (x0 + x1) / 2
        ys = _axis(y1 - y0, spacing) + (y0 + y1) / 2
        if not outline_only:
            return np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
        edges = [np.column_stack([xs, np.full_like(xs, ys[0])]), np.column_stack([xs, np.full_like(xs, ys[-1])]),
                 np.column_stack([np.full_like(ys, xs[0]), ys]), np.column_stack([np.full_like(ys, xs[-1]), ys])]
        return np.unique(np.concatenate(edges), axis=0)

    def outline(self, pose: Sequence[float]) -> np.ndarray:
        """Body rectangle corners at a pose, (4, 2) world (for plots)."""
        x0, x1, y0, y1 = self.body_rect()
        return transform(np.asarray(pose, float)[None], np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))[0]

    def wheel_centres(self, poses: np.ndarray) -> np.ndarray:
        """(N, 4, 2) world wheel contact centres at poses."""
        return transform(np.atleast_2d(poses), self.wheel_offsets())

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _axis(length: float, spacing: float) -> np.ndarray:
    n = max(2, int(math.ceil(length / spacing)) + 1)
    h = length / 2 - _INSET
    return np.linspace(-h, h, n)


def transform(poses: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Vehicle-frame points (K, 2) at poses (N, 3) -> world (N, K, 2)."""
    poses = np.asarray(poses, dtype=np.float64)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + c * local[None, :, 0] - s * local[None, :, 1]
    y = poses[:, 1:2] + s * local[None, :, 0] + c * local[None, :, 1]
    return np.stack([x, y], axis=-1)

