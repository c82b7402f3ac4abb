"""Rig files: which sensors sit where on the body, at what rate, with which parameters (TOML)::

    name = "survey"
    [[sensor]]
    name = "imu"                # the id: topics /imu, frame_id imu
    type = "imu"                # a registered sensor type (roadtwin plugins lists them)
    rate_hz = 200
    xyz = [0.0, 0.0, 1.2]       # m, in base_link (the body's CG frame: x forward, y left, z up)
    ypr_deg = [0.0, 0.0, 0.0]   # yaw, pitch (positive up), roll of the sensor's x axis in the body
    [sensor.params]             # the type's Params fields (checked like --param)
    accel_noise_density = 0.0017

Unknown keys, a duplicate id, a rate out of (0, 2000] Hz, an unknown type or parameter: one line.
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import RoadtwinError
from ...params import check_params, parse_param_options

DEFAULT_RIG = Path(__file__).with_name("default_rig.toml")
KEYS = {"name", "type", "rate_hz", "xyz", "ypr_deg", "params"}


@dataclass
class SensorSpec:
    id: str
    type: str
    rate_hz: float
    extrinsic: np.ndarray
    params: dict


def extrinsic(xyz, ypr_deg) -> np.ndarray:
    y, p, r = (math.radians(float(a)) for a in ypr_deg)
    cz, sz, cy, sy, cx, sx = math.cos(y), math.sin(y), math.cos(-p), math.sin(-p), math.cos(r), math.sin(r)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    m = np.eye(4)
    m[:3, :3] = Rz @ Ry @ Rx
    m[:3, 3] = np.asarray(xyz, dtype=np.float64)
    return m


def load_rig(path: Path | None) -> tuple[str, list[SensorSpec]]:
    path = Path(path) if path is not None else DEFAULT_RIG
    owner = f"rig file {path}"
    if not path.is_file():
        raise RoadtwinError(f"{owner}: no such file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RoadtwinError(f"{owner}: cannot parse ({str(exc).splitlines()[0]})") from None
    items = data.get("sensor")
    if not isinstance(items, list) or not items:
        raise RoadtwinError(f"{owner}: no [[sensor]] tables")
    specs, seen = [], set()
    for k, item in enumerate(items):
        where = f"{owner}: sensor {k}"
        unknown = sorted(set(item) - KEYS)
        if unknown:
            raise RoadtwinError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(KEYS))})")
        sid, typ = item.get("name"), item.get("type")
        if not (isinstance(sid, str) and re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", sid)):
            raise RoadtwinError(f"{where}: name must be an identifier (letters, digits, _), got {sid!r}")
        if sid in seen:
            raise RoadtwinError(f"{owner}: sensor name {sid!r} is used twice")
        seen.add(sid)
        rate = item.get("rate_hz")
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (0 < rate <= 2000):
            raise RoadtwinError(f"{owner}: sensor {sid}: rate_hz must be in (0, 2000], got {rate!r}")
        xyz, ypr = item.get("xyz", [0, 0, 0]), item.get("ypr_deg", [0, 0, 0])
        for key, v in (("xyz", xyz), ("ypr_deg", ypr)):
            if not (isinstance(v, list) and len(v) == 3 and all(isinstance(a, (int, float)) and not isinstance(a, bool)
                                                                and math.isfinite(a) for a in v)):
                raise RoadtwinError(f"{owner}: sensor {sid}: {key} must be 3 finite numbers, got {v!r}")
        if max(abs(a) for a in xyz) > 20:
            raise RoadtwinError(f"{owner}: sensor {sid}: xyz {xyz} is more than 20 m from the body")
        params = item.get("params", {})
        if not isinstance(params, dict):
            raise RoadtwinError(f"{owner}: sensor {sid}: params must be a table")
        specs.append(SensorSpec(sid, str(typ), float(rate), extrinsic(xyz, ypr), params))
    return str(data.get("name", path.stem)), specs


def select(specs: list[SensorSpec], names: str | None, rig_name: str) -> list[SensorSpec]:
    if not names:
        return specs
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    have = {s.id: s for s in specs}
    for n in wanted:
        if n not in have:
            raise RoadtwinError(f"rig {rig_name!r} has no sensor {n!r} (it has: {', '.join(have)})")
    return [have[n] for n in wanted]


def override(specs: list[SensorSpec], params: dict[str, dict], rig_name: str) -> list[SensorSpec]:
    """The rig's sensors with ``params`` (sensor id -> {parameter: value}) laid over their own
    (``roadtwin drive --sensor-param stereo.width=1280``): another resolution or noise model
    without another rig file. A sensor the selection does not hold is one line; the parameter
    names and values are checked by :func:`mount`, like the file's."""
    have = {s.id for s in specs}
    for sid in params:
        if sid not in have:
            raise RoadtwinError(f"--sensor-param {sid}.*: rig {rig_name!r} records no sensor {sid!r} "
                                f"(it records: {', '.join(sorted(have))})")
    return [SensorSpec(s.id, s.type, s.rate_hz, s.extrinsic, {**s.params, **params.get(s.id, {})}) for s in specs]


def parse_sensor_params(items) -> dict[str, dict]:
    """``["stereo.width=1280", "imu.gyro_noise_density=2e-4"]`` -> ``{"stereo": {"width": 1280}, ...}``
    (values as ``--param``'s: TOML scalars)."""
    out: dict[str, dict] = {}
    for item in items or ():
        sid, dot, rest = item.partition(".")
        if not dot or not sid.isidentifier():
            raise RoadtwinError(f"--sensor-param {item!r}: expected SENSOR.KEY=VALUE (e.g. stereo.width=1280)")
        try:
            (key, value), = parse_param_options([rest]).items()
        except RoadtwinError:
            raise RoadtwinError(f"--sensor-param {item!r}: expected SENSOR.KEY=VALUE (e.g. stereo.width=1280)") from None
        if key in out.setdefault(sid, {}):
            raise RoadtwinError(f"--sensor-param {sid}.{key}: given twice")
        out[sid][key] = value
    return out


def mount(pm, specs: list[SensorSpec]) -> list:
    """Create each sensor through its registered type, its params checked like ``--param``."""
    out = []
    for s in specs:
        sensor_type = pm.get("sensors", s.type)
        cls = sensor_type.Params
        fields = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(s.params) - fields)
        if unknown:
            raise RoadtwinError(f"sensor {s.id} ({s.type}): unknown parameter(s) {', '.join(unknown)} "
                                f"(known: {', '.join(sorted(fields))})")
        try:
            params = cls(**s.params)
        except TypeError as exc:
            raise RoadtwinError(f"sensor {s.id} ({s.type}): {exc}") from None
        params = check_params(params, f"sensor {s.id} ({s.type})")
        sensor = sensor_type.create(s.id, s.rate_hz, s.extrinsic, params)
        sensor.type, sensor.message = s.type, getattr(sensor, "message", sensor_type.message)
        out.append(sensor)
    return out
