"""What the built-in sensors share (numpy only): the mount (:class:`MountedSensor`: id, rate,
extrinsic, parameters and a noise generator seeded by the parameters' seed and the sensor's name),
the registered type that creates it (:class:`SensorType`), the camera optical frame, quaternions
and the LiDAR's range returns (:func:`returns`: the drive's LiDAR and the stand-alone scan
simulator keep, drop and perturb hits the same way)."""
from __future__ import annotations

import math

import numpy as np

# camera optical frame (x right, y down, z forward) expressed in a forward-looking sensor frame
# (x forward, y left, z up): the fixed rotation every ROS camera driver publishes
OPTICAL_IN_LINK = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of a rotation matrix (Shepperd, numerically safe)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.array(q)
    return q / np.linalg.norm(q)


class MountedSensor:
    """A sensor on the body: ``id``, ``rate_hz``, ``extrinsic`` (4x4, sensor in the body frame),
    ``params`` and ``rng`` (its own noise stream: the same drive, the same noise)."""

    message = ""

    def __init__(self, sensor_id: str, rate_hz: float, extrinsic, params) -> None:
        self.id, self.rate_hz, self.extrinsic, self.params = sensor_id, float(rate_hz), np.asarray(extrinsic), params
        self.rng = np.random.default_rng([params.seed, *sensor_id.encode()])


class SensorType:
    """A registered sensor type (the ``sensors`` plugin kind's contract): ``create`` mounts one
    ``sensor_class`` with the rig's id, rate, extrinsic and checked ``Params``."""

    name = description = message = ""
    Params: type
    sensor_class: type
    options: dict = {}

    def create(self, sensor_id, rate_hz, extrinsic, params):
        return self.sensor_class(sensor_id, rate_hz, extrinsic, params, **self.options)


def returns(t_hit: np.ndarray, rng: np.random.Generator, min_range_m: float, max_range_m: float, dropout: float,
            range_sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Which casts return (hit within range, not dropped at random) and their measured ranges
    (true range + Gaussian noise)."""
    keep = np.isfinite(t_hit) & (t_hit >= min_range_m) & (t_hit <= max_range_m)
    if dropout > 0:
        keep &= rng.random(len(t_hit)) >= dropout
    return keep, t_hit[keep] + rng.normal(0.0, range_sigma_m, int(keep.sum()))
