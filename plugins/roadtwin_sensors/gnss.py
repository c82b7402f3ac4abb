"""GNSS receiver: the antenna's position as WGS84 latitude / longitude / height, with RTK-fixed
or standalone (SPS) class errors, each a first-order Gauss-Markov process per axis (GNSS errors
are correlated in time, not white).

Defaults from the u-blox ZED-F9P data sheet (UBX-17051259): horizontal accuracy RTK 0.01 m +
1 ppm CEP, PVT (standalone) 1.5 m CEP; CEP = 1.1774 sigma for a circular Gaussian; vertical taken
as 1.5x (RTK) and 2x (SPS) the horizontal sigma. The town's local frame is put on the globe at
``lat0_deg``, ``lon0_deg``, ``alt0_m`` (east = +x, north = +y; local tangent plane).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadtwin_core import RoadtwinError, field

from ._mount import MountedSensor, SensorType

A_WGS84, E2_WGS84 = 6378137.0, 6.69437999014e-3


@dataclass
class GnssParams:
    mode: str = field("rtk", doc="rtk (RTK fixed) | sps (standalone)")
    rtk_cep_m: float = field(0.01, lo=0.0, hi=10.0, doc="RTK horizontal CEP, m (ZED-F9P: 0.01 m + 1 ppm)")
    sps_cep_m: float = field(1.5, lo=0.0, hi=100.0, doc="standalone horizontal CEP, m (ZED-F9P PVT: 1.5 m)")
    tau_s: float = field(0.0, lo=0.0, hi=3600.0, doc="error correlation time, s (0: 1 s RTK, 60 s SPS)")
    lat0_deg: float = field(31.2304, lo=-89.0, hi=89.0, doc="latitude of the town's origin")
    lon0_deg: float = field(121.4737, lo=-180.0, hi=180.0, doc="longitude of the town's origin")
    alt0_m: float = field(10.0, lo=-500.0, hi=9000.0, doc="ellipsoidal height of the town's origin")
    seed: int = field(0, lo=0, doc="noise seed (combined with the sensor's name)")


def enu_to_geodetic(enu: np.ndarray, lat0: float, lon0: float, alt0: float) -> tuple[float, float, float]:
    """Local tangent plane (east, north, up) -> (lat deg, lon deg, height m), WGS84 radii at the origin."""
    phi = math.radians(lat0)
    s = math.sin(phi)
    n_rad = A_WGS84 / math.sqrt(1 - E2_WGS84 * s * s)          # prime vertical
    m_rad = A_WGS84 * (1 - E2_WGS84) / (1 - E2_WGS84 * s * s) ** 1.5  # meridian
    e, n, u = (float(v) for v in enu)
    return (lat0 + math.degrees(n / (m_rad + alt0)), lon0 + math.degrees(e / ((n_rad + alt0) * math.cos(phi))),
            alt0 + u)


class GnssSensor(MountedSensor):
    kind = "gnss"
    message = "gnss"

    def __init__(self, sensor_id, rate_hz, extrinsic, params: GnssParams) -> None:
        if params.mode not in ("rtk", "sps"):
            raise RoadtwinError(f"sensor {sensor_id}: gnss mode must be rtk or sps, got {params.mode!r}")
        super().__init__(sensor_id, rate_hz, extrinsic, params)
        cep = params.rtk_cep_m if params.mode == "rtk" else params.sps_cep_m
        sh = cep / 1.1774
        self.sigma = np.array([sh, sh, sh * (1.5 if params.mode == "rtk" else 2.0)])
        self.tau = params.tau_s or (1.0 if params.mode == "rtk" else 60.0)
        self.err = self.rng.normal(0.0, 1.0, 3) * self.sigma

    def sample(self, state, world) -> dict:
        p = self.params
        dt = 1.0 / self.rate_hz
        a = math.exp(-dt / self.tau)
        self.err = a * self.err + math.sqrt(1 - a * a) * self.sigma * self.rng.normal(0.0, 1.0, 3)
        T = state.pose_at(state.t) @ self.extrinsic
        true = T[:3, 3]
        extra = 1e-6 * float(np.hypot(*true[:2])) if p.mode == "rtk" else 0.0   # the 1 ppm baseline term
        meas = true + self.err + (self.rng.normal(0.0, extra, 3) if extra else 0.0)
        lat, lon, alt = enu_to_geodetic(meas, p.lat0_deg, p.lon0_deg, p.alt0_m)
        var = (self.sigma + extra) ** 2
        return {"t": state.t, "latitude": lat, "longitude": lon, "altitude": alt, "covariance": np.diag(var),
                "status": 2 if p.mode == "rtk" else 0, "truth": {"enu": true}}


class Gnss(SensorType):
    name = "gnss"
    description = "GNSS antenna position (WGS84) with RTK-fixed or standalone errors (Gauss-Markov; u-blox ZED-F9P figures)"
    Params = GnssParams
    message = "gnss"
    sensor_class = GnssSensor
