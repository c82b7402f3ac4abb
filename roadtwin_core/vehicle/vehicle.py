"""Vehicle parameters: a validated full car (and a quarter car), read from TOML or JSON.

The full vehicle (used by every physics backend) is a sprung body on four independent vertical
suspensions with tires as radial springs:

* **body**: a rigid body of ``sprung_mass_kg`` with principal inertias (roll, pitch, yaw) about
  its centre of gravity (CG). Body frame: x forward, y left, z up; orientation
  R = Rz(yaw) Ry(pitch) Rx(roll); positive pitch is nose down, positive roll is left side up.
* **suspension** (one per corner, FL FR RL RR): the wheel centre slides along the body z axis
  below its corner (x = +a front / -b rear, y = +-track/2). A linear spring (free length at
  compression s = 0) and a linear damper act between body and wheel; past the travel limits
  (``jounce_travel_m`` above, ``rebound_travel_m`` below the static position) a stiff stop
  (``stop_stiffness_n_per_m``, ``stop_damping_ns_per_m``) takes over.
* **wheel/tire**: ``unsprung_mass_kg`` per corner (a point mass at the wheel centre, locked to
  the body's orientation) and a tire of ``tire_radius_m`` x ``tire_width_m`` whose radial
  stiffness ``tire_stiffness_n_per_m`` and damping act where the tire's lower arc penetrates the
  road (the backends sample that arc; see the plugins).

Geometry is given at the *static* ride position on flat ground: ``cg_height_m`` is the CG height
with the car at rest. The spring free lengths follow from it (the car sags onto its springs and
tires by exactly the static loads), which is what the static-sag validation test checks.

Files: TOML or JSON, either flat or grouped in tables (``[body]``, ``[suspension]``,
``[tire]``; the table names are only for readability). Every parameter must be given, unless the
file says ``extends = "default"``, in which case missing ones come from :data:`DEFAULT_CAR`.
Unknown keys, missing keys, NaN, non-positive masses/stiffnesses/lengths, impossible inertias or
geometry, and a car that would sit on its bump stops raise :class:`RoadtwinError` with one line
naming the file and the parameter.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RoadtwinError
from ..params import check_params, field

GRAVITY = 9.81  # m/s^2, as in the composed stages' physics scene

CORNERS = ("FL", "FR", "RL", "RR")


def _f(default: float, unit: str, doc: str, *, positive: bool = True, lo: float | None = None,
       hi: float | None = None) -> Any:
    """A :func:`roadtwin_core.params.field` (bounds ``lo``/``hi``) with a unit, and > 0 unless
    ``positive=False``."""
    base = field(default, lo=lo, hi=hi, doc=doc)
    return dataclasses.field(default=default, metadata={**base.metadata, "unit": unit, "positive": positive})


@dataclass(frozen=True)
class VehicleParams:
    """A passenger car. Defaults: a compact sedan (about 1.46 t with wheels), body modes about
    1.3 Hz (front) / 1.5 Hz (rear) at 30 % damping, wheel hop about 12 Hz."""

    name: str = "default_car"
    # body
    sprung_mass_kg: float = _f(1300.0, "kg", "sprung (body) mass", hi=1e5)
    roll_inertia_kgm2: float = _f(450.0, "kg m^2", "body inertia about the CG's x axis")
    pitch_inertia_kgm2: float = _f(1800.0, "kg m^2", "body inertia about the CG's y axis")
    yaw_inertia_kgm2: float = _f(2000.0, "kg m^2", "body inertia about the CG's z axis")
    wheelbase_m: float = _f(2.70, "m", "front axle to rear axle", hi=20.0)
    cg_to_front_axle_m: float = _f(1.10, "m", "CG to front axle (a); CG to rear axle is wheelbase - a")
    track_front_m: float = _f(1.55, "m", "front wheel centre to wheel centre", hi=5.0)
    track_rear_m: float = _f(1.55, "m", "rear wheel centre to wheel centre", hi=5.0)
    cg_height_m: float = _f(0.55, "m", "CG height above flat ground at rest", hi=5.0)
    imu_x_m: float = _f(0.0, "m", "IMU position from the CG, body x", positive=False, lo=-5.0, hi=5.0)
    imu_y_m: float = _f(0.0, "m", "IMU position from the CG, body y", positive=False, lo=-5.0, hi=5.0)
    imu_z_m: float = _f(0.0, "m", "IMU position from the CG, body z", positive=False, lo=-5.0, hi=5.0)
    # suspension
    spring_front_n_per_m: float = _f(30000.0, "N/m", "front spring rate at the wheel")
    spring_rear_n_per_m: float = _f(26000.0, "N/m", "rear spring rate at the wheel")
    damper_front_ns_per_m: float = _f(2200.0, "N s/m", "front damping at the wheel")
    damper_rear_ns_per_m: float = _f(2000.0, "N s/m", "rear damping at the wheel")
    jounce_travel_m: float = _f(0.08, "m", "static position to bump stop (compression)", hi=1.0)
    rebound_travel_m: float = _f(0.10, "m", "static position to rebound stop (extension)", hi=1.0)
    stop_stiffness_n_per_m: float = _f(200000.0, "N/m", "bump/rebound stop stiffness")
    stop_damping_ns_per_m: float = _f(1500.0, "N s/m", "bump/rebound stop damping", positive=False, lo=0.0)
    # wheel and tire
    unsprung_mass_kg: float = _f(40.0, "kg", "wheel, tire, hub, brake per corner")
    tire_radius_m: float = _f(0.31, "m", "unloaded tire radius", hi=2.0)
    tire_width_m: float = _f(0.205, "m", "tread width", hi=1.5)
    tire_stiffness_n_per_m: float = _f(220000.0, "N/m", "radial stiffness")
    tire_damping_ns_per_m: float = _f(100.0, "N s/m", "radial damping", positive=False, lo=0.0)
    # footprint (planning; optional in files, see FOOTPRINT_FIELDS)
    tire_contact_length_m: float = _f(0.15, "m", "tire contact patch length (planning footprint)", hi=2.0)
    body_length_m: float = _f(4.5, "m", "body length, bumper to bumper (planning footprint)", hi=30.0)
    body_width_m: float = _f(1.8, "m", "body width (planning footprint; never narrower than the outer tire edges)",
                             hi=5.0)
    rear_overhang_m: float = _f(0.9, "m", "rear bumper behind the rear axle (planning footprint)", hi=10.0)
    max_steer_rad: float = _f(0.6, "rad", "front wheel steering angle at full lock (planning footprint)",
                              hi=1.5)

    # ------------------------------------------------------------------ derived quantities
    @property
    def total_mass_kg(self) -> float:
        return self.sprung_mass_kg + 4 * self.unsprung_mass_kg

    @property
    def cg_to_rear_axle_m(self) -> float:
        return self.wheelbase_m - self.cg_to_front_axle_m

    def corner_loads_n(self) -> tuple[float, float, float, float]:
        """Static sprung load per corner (N): the axle loads from the pitch moment balance,
        split equally left/right (the CG is on the centreline)."""
        w = self.sprung_mass_kg * GRAVITY
        front = w * self.cg_to_rear_axle_m / self.wheelbase_m / 2
        rear = w * self.cg_to_front_axle_m / self.wheelbase_m / 2
        return front, front, rear, rear

    def corner(self, i: int) -> dict[str, float]:
        """Everything a backend needs about corner ``i`` (0..3 = FL FR RL RR)."""
        front = i < 2
        left = i % 2 == 0
        track = self.track_front_m if front else self.track_rear_m
        ks = self.spring_front_n_per_m if front else self.spring_rear_n_per_m
        cs = self.damper_front_ns_per_m if front else self.damper_rear_ns_per_m
        load = self.corner_loads_n()[i]
        s_static = load / ks                                  # spring compression at rest
        tire_defl = (load + self.unsprung_mass_kg * GRAVITY) / self.tire_stiffness_n_per_m
        wheel_z = self.tire_radius_m - tire_defl              # wheel centre height at rest
        e_static = self.cg_height_m - wheel_z                 # CG to wheel centre along body -z
        return {"x": self.cg_to_front_axle_m if front else -self.cg_to_rear_axle_m,
                "y": track / 2 if left else -track / 2, "ks": ks, "cs": cs, "load": load,
                "s_static": s_static, "tire_deflection": tire_defl,
                "e_free": e_static + s_static,                # wheel centre below CG at s = 0
                "s_min": s_static - self.rebound_travel_m, "s_max": s_static + self.jounce_travel_m}

    def to_plain(self) -> dict[str, Any]:
        """The backend contract: plain floats (no roadtwin types), see the plugins' docs.

        Keys: mode ("full"), m_b, ixx, iyy, izz, m_u, radius, width, kt, ct, k_stop, c_stop,
        imu (3 floats, body frame from the CG), cg_height, corners (4 dicts of :meth:`corner`).
        """
        return {"mode": "full", "name": self.name, "m_b": self.sprung_mass_kg, "ixx": self.roll_inertia_kgm2,
                "iyy": self.pitch_inertia_kgm2, "izz": self.yaw_inertia_kgm2, "m_u": self.unsprung_mass_kg,
                "radius": self.tire_radius_m, "width": self.tire_width_m, "kt": self.tire_stiffness_n_per_m,
                "ct": self.tire_damping_ns_per_m, "k_stop": self.stop_stiffness_n_per_m,
                "c_stop": self.stop_damping_ns_per_m, "imu": [self.imu_x_m, self.imu_y_m, self.imu_z_m],
                "cg_height": self.cg_height_m, "wheelbase": self.wheelbase_m,
                "corners": [self.corner(i) for i in range(4)], "gravity": GRAVITY}

    def footprint(self):
        """The vehicle as planning sees it (:class:`roadtwin_core.planning.Footprint`).

        Planning's wheel-level check puts each axle's wheels ``track/2`` either side of the
        centreline with one track, so a car whose front and rear tracks differ is refused
        rather than planned with the wrong wheel lines."""
        from ..planning import Footprint   # planning needs scipy; vehicle imports with numpy alone (GPU side)

        if abs(self.track_front_m - self.track_rear_m) > 1e-9:
            raise RoadtwinError(f"vehicle {self.name}: planning needs track_front_m == track_rear_m "
                                f"(got {self.track_front_m} and {self.track_rear_m})")
        return Footprint(track_m=self.track_rear_m, wheelbase_m=self.wheelbase_m, tire_width_m=self.tire_width_m,
                         tire_length_m=self.tire_contact_length_m, body_length_m=self.body_length_m,
                         body_width_m=self.body_width_m, rear_overhang_m=self.rear_overhang_m,
                         max_steer_rad=self.max_steer_rad)

    def quarter_car(self, corner: int = 0) -> "QuarterCarParams":
        """The 2-DOF quarter car of one corner (its static sprung load, spring, damper, tire)."""
        c = self.corner(corner)
        return QuarterCarParams(name=f"{self.name}:{CORNERS[corner]}", sprung_mass_kg=c["load"] / GRAVITY,
                                unsprung_mass_kg=self.unsprung_mass_kg, spring_n_per_m=c["ks"],
                                damper_ns_per_m=c["cs"], tire_stiffness_n_per_m=self.tire_stiffness_n_per_m,
                                tire_damping_ns_per_m=self.tire_damping_ns_per_m, tire_radius_m=self.tire_radius_m)

    def check(self, owner: str = "vehicle") -> "VehicleParams":
        _check_fields(self, owner)
        a, L = self.cg_to_front_axle_m, self.wheelbase_m
        if not a < L:
            raise RoadtwinError(f"{owner}: cg_to_front_axle_m ({a}) must be less than wheelbase_m ({L})")
        ix, iy, iz = self.roll_inertia_kgm2, self.pitch_inertia_kgm2, self.yaw_inertia_kgm2
        for name, i, j, k in (("roll", ix, iy, iz), ("pitch", iy, iz, ix), ("yaw", iz, ix, iy)):
            if i > j + k:
                raise RoadtwinError(f"{owner}: {name}_inertia_kgm2 ({i}) exceeds the sum of the other two principal "
                                    f"inertias ({j} + {k}): no rigid body has such inertias")
        for track in ("track_front_m", "track_rear_m"):
            if self.tire_width_m >= getattr(self, track):
                raise RoadtwinError(f"{owner}: tire_width_m ({self.tire_width_m}) must be less than {track}")
        for i in range(4):
            c = self.corner(i)
            if c["tire_deflection"] > 0.3 * self.tire_radius_m:
                raise RoadtwinError(f"{owner}: static tire deflection at {CORNERS[i]} is {c['tire_deflection']:.3f} m "
                                    f"(> 30 % of tire_radius_m): tire_stiffness_n_per_m is too low for the load")
            if c["e_free"] <= 0:
                raise RoadtwinError(f"{owner}: cg_height_m ({self.cg_height_m}) puts the CG below the free spring "
                                    f"position at {CORNERS[i]}: raise cg_height_m or stiffen the springs")
        if self.body_length_m < self.wheelbase_m + self.rear_overhang_m:
            raise RoadtwinError(f"{owner}: body_length_m ({self.body_length_m}) must cover rear_overhang_m + "
                                f"wheelbase_m ({self.rear_overhang_m} + {self.wheelbase_m})")
        if self.stop_stiffness_n_per_m < max(self.spring_front_n_per_m, self.spring_rear_n_per_m):
            raise RoadtwinError(f"{owner}: stop_stiffness_n_per_m ({self.stop_stiffness_n_per_m}) must be at least "
                                f"the spring rates: a travel stop softer than the spring is not a stop")
        return self


@dataclass(frozen=True)
class QuarterCarParams:
    """The 2-DOF quarter car (validation): sprung mass ms on spring ks and damper cs over an
    unsprung mass mu on a tire kt (point contact under the wheel centre, lift-off allowed)."""

    name: str = "quarter_car"
    sprung_mass_kg: float = _f(300.0, "kg", "sprung mass ms", hi=1e5)
    unsprung_mass_kg: float = _f(40.0, "kg", "unsprung mass mu", hi=1e4)
    spring_n_per_m: float = _f(25000.0, "N/m", "suspension stiffness ks")
    damper_ns_per_m: float = _f(2000.0, "N s/m", "suspension damping cs")
    tire_stiffness_n_per_m: float = _f(220000.0, "N/m", "tire stiffness kt")
    tire_damping_ns_per_m: float = _f(0.0, "N s/m", "tire damping ct", positive=False, lo=0.0)
    tire_radius_m: float = _f(0.31, "m", "tire radius (sets the wheel centre height only)", hi=2.0)

    def check(self, owner: str = "quarter car") -> "QuarterCarParams":
        _check_fields(self, owner)
        defl = (self.sprung_mass_kg + self.unsprung_mass_kg) * GRAVITY / self.tire_stiffness_n_per_m
        if defl > 0.3 * self.tire_radius_m:
            raise RoadtwinError(f"{owner}: static tire deflection {defl:.3f} m exceeds 30 % of tire_radius_m")
        return self

    def to_plain(self) -> dict[str, Any]:
        s_static = self.sprung_mass_kg * GRAVITY / self.spring_n_per_m
        return {"mode": "quarter", "name": self.name, "m_s": self.sprung_mass_kg, "m_u": self.unsprung_mass_kg,
                "ks": self.spring_n_per_m, "cs": self.damper_ns_per_m, "kt": self.tire_stiffness_n_per_m,
                "ct": self.tire_damping_ns_per_m, "radius": self.tire_radius_m, "s_static": s_static,
                "e_free": 0.3 + s_static, "gravity": GRAVITY}


def _check_fields(obj: Any, owner: str) -> None:
    for f in dataclasses.fields(obj):
        if f.name == "name":
            if not isinstance(obj.name, str) or not obj.name:
                raise RoadtwinError(f"{owner}: name must be a non-empty string")
            continue
        v = getattr(obj, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise RoadtwinError(f"{owner}: {f.name} must be a number, got {v!r}")
    check_params(obj, owner)          # finite, within lo/hi
    for f in dataclasses.fields(obj):
        if f.metadata.get("positive") and getattr(obj, f.name) <= 0:
            raise RoadtwinError(f"{owner}: {f.name} must be > 0 ({f.metadata['unit']}), got {float(getattr(obj, f.name))}")


DEFAULT_CAR = VehicleParams()

# Planning-only parameters: a vehicle file may leave them out (the default car's values are used),
# so vehicle files written before planning shared this description still load.
FOOTPRINT_FIELDS = ("tire_contact_length_m", "body_length_m", "body_width_m", "rear_overhang_m", "max_steer_rad")

PAPER_CAR_FILE = Path(__file__).with_name("paper_car.toml")


def paper_car() -> VehicleParams:
    """Zhang et al.'s planning vehicle (2.0 m track, 3.0 m wheelbase): ``paper_car.toml``,
    the default of ``roadtwin plan``."""
    return load_vehicle(PAPER_CAR_FILE)


def parameter_names(cls: type = VehicleParams) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if f.name != "name"]


def _flatten(data: dict, owner: str) -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, dict):  # a [table]: names are for readability only
            for k2, v2 in v.items():
                if isinstance(v2, dict):
                    raise RoadtwinError(f"{owner}: nested table {k}.{k2} is not allowed")
                if k2 in flat:
                    raise RoadtwinError(f"{owner}: parameter {k2} is given twice")
                flat[k2] = v2
        else:
            if k in flat:
                raise RoadtwinError(f"{owner}: parameter {k} is given twice")
            flat[k] = v
    return flat


def vehicle_from_dict(data: dict, owner: str = "vehicle") -> VehicleParams | QuarterCarParams:
    """Build and check parameters from a (possibly table-grouped) mapping.

    ``model = "quarter"`` selects :class:`QuarterCarParams` (default ``"full"``);
    ``extends = "default"`` fills missing parameters from the defaults.
    """
    if not isinstance(data, dict):
        raise RoadtwinError(f"{owner}: expected a table of parameters")
    flat = _flatten(data, owner)
    model = str(flat.pop("model", "full"))
    extends = flat.pop("extends", None)
    if model not in ("full", "quarter"):
        raise RoadtwinError(f"{owner}: model must be \"full\" or \"quarter\", got {model!r}")
    cls = VehicleParams if model == "full" else QuarterCarParams
    names = parameter_names(cls)
    unknown = sorted(set(flat) - set(names) - {"name"})
    if unknown:
        raise RoadtwinError(f"{owner}: unknown parameter(s) {', '.join(unknown)} (known: {', '.join(names)})")
    if extends is not None and extends != "default":
        raise RoadtwinError(f"{owner}: extends must be \"default\", got {extends!r}")
    missing = [n for n in names if n not in flat and n not in FOOTPRINT_FIELDS]
    if missing and extends is None:
        raise RoadtwinError(f"{owner}: missing parameter(s) {', '.join(missing)} "
                            f"(give them all, or add extends = \"default\" to take the rest from the default car)")
    if "name" in flat and (not isinstance(flat["name"], str) or not flat["name"].strip()):
        raise RoadtwinError(f"{owner}: name must be a non-empty string, got {flat['name']!r}")
    for k, v in flat.items():
        if k != "name" and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise RoadtwinError(f"{owner}: {k} must be a number, got {v!r}")
    params = cls(**{k: (float(v) if k != "name" else str(v)) for k, v in flat.items()})
    return params.check(owner)


def load_vehicle(path: str | Path) -> VehicleParams | QuarterCarParams:
    """Read a vehicle file (``.toml`` or ``.json``)."""
    path = Path(path)
    owner = f"vehicle file {path}"
    if path.is_dir():
        raise RoadtwinError(f"{owner}: is a directory, not a vehicle file")
    if not path.is_file():
        raise RoadtwinError(f"{owner}: no such file")
    text = path.read_bytes()
    suffix = path.suffix.lower()
    try:
        if suffix == ".json":
            data = json.loads(text)
        elif suffix == ".toml":
            data = tomllib.loads(text.decode("utf-8"))
        else:
            raise RoadtwinError(f"{owner}: unknown format {suffix or '(none)'} (use .toml or .json)")
    except (ValueError, UnicodeDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RoadtwinError(f"{owner}: cannot parse: {first}") from None
    if not isinstance(data, dict):
        raise RoadtwinError(f"{owner}: expected a table of parameters, got a JSON {type(data).__name__}")
    data = dict(data)
    data.setdefault("name", path.stem)
    return vehicle_from_dict(data, owner)


def load_full_vehicle(path: str | Path | None, default: VehicleParams) -> VehicleParams:
    """The ``--vehicle FILE`` option of ``plan`` and ``sweep``: ``default`` without a file; a
    quarter car is refused (both commands drive or plan the whole car)."""
    if path is None:
        return default
    params = load_vehicle(path)
    if not isinstance(params, VehicleParams):
        raise RoadtwinError(f"vehicle file {path}: needs a full vehicle (model = \"full\"), not a quarter car")
    return params


def vehicle_to_toml(params: VehicleParams) -> str:
    """A complete, commented vehicle file (what ``default_car.toml`` is)."""
    groups = {"body": ("sprung_mass_kg", "roll_inertia_kgm2", "pitch_inertia_kgm2", "yaw_inertia_kgm2",
                       "wheelbase_m", "cg_to_front_axle_m", "track_front_m", "track_rear_m", "cg_height_m",
                       "imu_x_m", "imu_y_m", "imu_z_m"),
              "suspension": ("spring_front_n_per_m", "spring_rear_n_per_m", "damper_front_ns_per_m",
                             "damper_rear_ns_per_m", "jounce_travel_m", "rebound_travel_m",
                             "stop_stiffness_n_per_m", "stop_damping_ns_per_m"),
              "tire": ("unsprung_mass_kg", "tire_radius_m", "tire_width_m", "tire_stiffness_n_per_m",
                       "tire_damping_ns_per_m"),
              "footprint": FOOTPRINT_FIELDS}
    meta = {f.name: f.metadata for f in dataclasses.fields(params)}
    lines = [f'name = "{params.name}"', 'model = "full"', ""]
    for g, names in groups.items():
        lines.append(f"[{g}]")
        for n in names:
            lines.append(f"{n} = {getattr(params, n)!r}  # {meta[n]['unit']}: {meta[n]['doc']}")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- backend contract
@dataclass
class SimParams:
    """What every physics backend's ``simulate`` takes besides the road and the vehicles."""

    dt_s: float = 1e-3                  # fixed integration step
    imu_rate_hz: float = 500.0          # IMU samples per second (each the mean over its interval)
    device: str = "cpu"                 # warp: cpu | cuda | cuda:N ; pybullet: cpu only
    tire_slices: int = 3                # lateral slices across the tread
    tire_arc_samples: int = 7           # rays per slice over the lower arc
    tire_arc_deg: float = 45.0          # half angle of the sampled arc (0 = straight down only)
    tire_refine: int = 2                # bisection rounds (2 rays each) around each slice's deepest ray
    lost_after_s: float = 1.0           # a wheel off the mesh this long ends the run (off_road)

    def check(self, owner: str = "simulation") -> "SimParams":
        if not (math.isfinite(self.dt_s) and 0 < self.dt_s <= 0.005):
            raise RoadtwinError(f"{owner}: dt must be in (0, 0.005] s, got {self.dt_s}")
        if not (math.isfinite(self.imu_rate_hz) and 0 < self.imu_rate_hz <= 1.0 / self.dt_s + 1e-9):
            raise RoadtwinError(f"{owner}: IMU rate must be in (0, 1/dt] Hz, got {self.imu_rate_hz}")
        if not (1 <= int(self.tire_slices) <= 15 and 1 <= int(self.tire_arc_samples) <= 63):
            raise RoadtwinError(f"{owner}: tire sampling must be 1..15 slices x 1..63 arc samples")
        if not (0 <= int(self.tire_refine) <= 8):
            raise RoadtwinError(f"{owner}: tire refinement rounds must be 0..8, got {self.tire_refine}")
        if not (0 <= self.tire_arc_deg <= 80):
            raise RoadtwinError(f"{owner}: tire arc half angle must be in [0, 80] degrees, got {self.tire_arc_deg}")
        if not isinstance(self.device, str) or not re.fullmatch(r"cpu|cuda(:\d+)?", self.device):
            raise RoadtwinError(f"{owner}: device must be cpu, cuda or cuda:N, got {self.device!r}")
        if not (math.isfinite(self.lost_after_s) and self.lost_after_s > 0):
            raise RoadtwinError(f"{owner}: lost_after_s must be > 0, got {self.lost_after_s}")
        return self


@dataclass
class VehicleRun:
    """One vehicle of a batch: its parameters and where/how fast it drives.

    The CG follows ``path`` (world XY polyline, lateral offset already applied) at constant
    ``speed`` (m/s), starting ``s0`` meters along it, for ``duration`` seconds. It starts at rest
    on its springs over the road under its wheels, unless ``initial_state`` overrides
    (``q`` = (z, roll, pitch) or quarter (z_body, z_wheel, 0), ``qd``, ``s``, ``sd``).
    """

    params: Any
    path: Any
    s0: float
    speed: float
    duration: float
    initial_state: dict | None = None


@dataclass
class Traces:
    """A batch's output, sampled at the IMU rate (NaN after a vehicle's own end).

    ``t`` (T,) sample times (s); ``acc`` (N,T,3) specific force in the body frame (m/s^2, +9.81
    on z at rest); ``gyro`` (N,T,3) body angular rate (rad/s); ``pose`` (N,T,6) CG x, y, z,
    roll, pitch, yaw; ``wheel_z`` (N,T,4) wheel centre heights; ``tire_f`` (N,T,4) tire normal
    loads (N); ``susp`` (N,T,4) suspension compression from static (m); ``valid`` (N,) samples
    per vehicle; ``off_road`` (N,) a wheel lost the road for ``lost_after_s``; ``meta``: backend,
    device, wall_s (simulation wall time), sim_s (simulated vehicle-seconds), setup_s ...
    """

    t: Any
    acc: Any
    gyro: Any
    pose: Any
    wheel_z: Any
    tire_f: Any
    susp: Any
    valid: Any
    off_road: Any
    meta: dict

    @property
    def realtime_factor(self) -> float:
        return float(self.meta["sim_s"] / max(self.meta["wall_s"], 1e-12))


def plain_vehicles(runs: list[VehicleRun]) -> list[dict]:
    """The plain dicts the standalone simulators take (parameter dicts shared by identity)."""
    cache: dict[int, dict] = {}
    out = []
    for r in runs:
        key = id(r.params)
        if key not in cache:
            cache[key] = r.params.to_plain()
        out.append({"params": cache[key], "path": r.path, "s0": float(r.s0), "speed": float(r.speed),
                    "duration": float(r.duration)})
    return out


def check_runs(runs: list[VehicleRun], owner: str = "simulation") -> None:
    if not runs:
        raise RoadtwinError(f"{owner}: no vehicles to simulate")
    kinds = {type(r.params) for r in runs}
    if len(kinds) != 1 or not kinds <= {VehicleParams, QuarterCarParams}:
        raise RoadtwinError(f"{owner}: one batch takes either full vehicles or quarter cars, of roadtwin's types")
    for i, r in enumerate(runs):
        if not (math.isfinite(r.speed) and r.speed >= 0):
            raise RoadtwinError(f"{owner}: vehicle {i}: speed must be >= 0 m/s, got {r.speed}")
        if not (math.isfinite(r.duration) and r.duration > 0):
            raise RoadtwinError(f"{owner}: vehicle {i}: duration must be > 0 s, got {r.duration}")
        p = np.asarray(r.path, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2 or not np.isfinite(p).all():
            raise RoadtwinError(f"{owner}: vehicle {i}: path must be a finite (K>=2, 2) polyline")
