"""IMU: the body's specific force and rate at the mount, averaged over each sample interval (a
delta-velocity IMU), plus white noise, a turn-on bias and a bias random walk per axis.

Defaults: a Bosch BMI088. These are the data sheet's *typical* values (BST-BMI088-DS001), not
limits, and were checked against published quotes of the data sheet, not the PDF itself:
accelerometer output noise density 175 ug/sqrt(Hz) (the figure quoted from revisions 1.3/1.4;
revision 1.9 is quoted as 160 ug/sqrt(Hz) for x and y, 190 for z), zero-g offset 20 mg; gyroscope
rate noise density 0.014 deg/s/sqrt(Hz), zero-rate offset 1 deg/s. The data sheet gives no bias
instability or random-walk figures: the two random walks below are assumptions (the gyro's
chosen so its bias wanders by about 2 deg/h, a figure quoted for the BMI088 outside the data
sheet, over 100 s), to be replaced by an Allan-variance fit of a real unit. (The Livox Mid-360's
built-in IMU is a TDK ICM40609; give its figures in the rig file's ``[sensor.params]``.)
Discrete white noise sigma = density x sqrt(rate) (the continuous-time density of a sample
averaged over 1 / rate, as Kalibr and the ROS IMU tools read such figures).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import field

from ._mount import MountedSensor, SensorType, quat_xyzw

G = 9.80665


@dataclass
class ImuParams:
    accel_noise_density: float = field(175e-6 * G, lo=0.0, hi=1.0,
                                       doc="accelerometer white noise, m/s^2/sqrt(Hz) (BMI088 typical: 175 ug/sqrt(Hz))")
    gyro_noise_density: float = field(math.radians(0.014), lo=0.0, hi=1.0,
                                      doc="gyro white noise, rad/s/sqrt(Hz) (BMI088 typical: 0.014 deg/s/sqrt(Hz))")
    accel_bias_sigma: float = field(20e-3 * G, lo=0.0, hi=10.0,
                                    doc="turn-on accelerometer bias, 1 sigma, m/s^2 (BMI088 typical zero-g offset 20 mg)")
    gyro_bias_sigma: float = field(math.radians(1.0), lo=0.0, hi=1.0,
                                   doc="turn-on gyro bias, 1 sigma, rad/s (BMI088 typical zero-rate offset 1 deg/s)")
    accel_random_walk: float = field(1e-4, lo=0.0, hi=1.0,
                                     doc="accelerometer bias random walk, m/s^3/sqrt(Hz) (assumed: not in the data sheet)")
    gyro_random_walk: float = field(math.radians(2.0 / 3600.0) / 10.0, lo=0.0, hi=1.0,
                                    doc="gyro bias random walk, rad/s^2/sqrt(Hz) (assumed: ~2 deg/h over 100 s; not in "
                                        "the data sheet)")
    seed: int = field(0, lo=0, doc="noise seed (combined with the sensor's name)")


class ImuSensor(MountedSensor):
    kind = "imu"
    message = "imu"

    def __init__(self, sensor_id: str, rate_hz: float, extrinsic: np.ndarray, params: ImuParams) -> None:
        super().__init__(sensor_id, rate_hz, extrinsic, params)
        self.bias_a = self.rng.normal(0.0, params.accel_bias_sigma, 3)
        self.bias_g = self.rng.normal(0.0, params.gyro_bias_sigma, 3)

    def sample(self, state, world) -> dict:
        p, dt = self.params, 1.0 / self.rate_hz
        R_bs = self.extrinsic[:3, :3]
        f_b, w_b = state.imu_truth(self.extrinsic[:3, 3], state.t - dt, state.t)
        f_s, w_s = R_bs.T @ f_b, R_bs.T @ w_b
        self.bias_a += self.rng.normal(0.0, p.accel_random_walk * math.sqrt(dt), 3)
        self.bias_g += self.rng.normal(0.0, p.gyro_random_walk * math.sqrt(dt), 3)
        acc = f_s + self.bias_a + self.rng.normal(0.0, p.accel_noise_density * math.sqrt(self.rate_hz), 3)
        gyro = w_s + self.bias_g + self.rng.normal(0.0, p.gyro_noise_density * math.sqrt(self.rate_hz), 3)
        R_ws = state.pose_at(state.t)[:3, :3] @ R_bs
        return {"t": state.t, "linear_acceleration": acc, "angular_velocity": gyro, "orientation": quat_xyzw(R_ws),
                "accel_var": (p.accel_noise_density ** 2) * self.rate_hz, "gyro_var": (p.gyro_noise_density ** 2) * self.rate_hz,
                "truth": {"specific_force": f_s, "rate": w_s}}


class Imu(SensorType):
    name = "imu"
    description = "IMU: specific force + body rate at the mount, white noise, turn-on bias, bias random walk (BMI088 defaults)"
    Params = ImuParams
    message = "imu"
    sensor_class = ImuSensor
