"""What each kind of plugin object must provide, as ``typing.Protocol`` classes.

The hook specs (:mod:`roadtwin_core.hookspecs`) say *when* a plugin registers things; these
protocols say *what* a registered thing is. The plugin manager checks every registered object
with :func:`check` when it registers it, so a thing written against an older or misread contract
is reported by plugin name (like an import error) instead of failing with ``AttributeError`` in
the middle of a command. Why an explicit checker and not ``isinstance(thing, Protocol)``: a
runtime-checkable protocol only tests that names exist; :func:`check` also tests that each method
can be called with the arguments the core passes, and that ``Params`` is a dataclass.

Optional renderer capabilities are not probed for with ``hasattr``: :class:`Renderer` declares
them, and :class:`RendererBase` gives the do-nothing defaults a renderer inherits when it has
nothing better to do.
"""
from __future__ import annotations

import copy
import dataclasses
import inspect
from pathlib import Path
from typing import Any, Iterator, Literal, Protocol, runtime_checkable

__all__ = ["DefectType", "Reconstructor", "Merger", "LayoutImporter", "Renderer", "RendererBase",
           "PhysicsBackend", "Planner", "Exporter", "SurfaceSource", "DatasetFormat", "Sensor", "PROTOCOLS", "check",
           "params_class", "configured"]


@runtime_checkable
class DefectType(Protocol):
    """A parametric defect generator. Same params and rng state give the same model.

    Three optional class attributes, read with defaults (a type without them is a defect at a
    random yaw in worn asphalt): ``semantic_class`` (default ``"road_defect"``; another class, e.g.
    a look-alike's ``"road_lookalike"``, is labelled ``["road", <class>, <name>]``), ``along_travel``
    (default False: True yaws instances with the lane, like ruts) and ``material`` (default
    ``"worn"``: the catalog material its surface wears, one of ``roadtwin_core.looks.all_materials()``;
    a model with its own texture wears that instead). docs/plugins.md#roadtwin_register_defect_types."""

    name: str
    description: str
    Params: type

    def sample_params(self, rng) -> Any:
        """A plausible random ``Params`` instance."""

    def generate(self, params, rng, name) -> Any:
        """``params`` -> a :class:`~roadtwin_core.DefectModel` called ``name``."""


@runtime_checkable
class Reconstructor(Protocol):
    """Sensor data -> a surface or defect models, in two steps so the CLI can report before writing.

    ``produces`` is ``"surface"`` (``roadtwin reconstruct surface``) or ``"defects"``
    (``roadtwin reconstruct defects``, and ``reconstruct photos`` for a photo reconstructor) or
    ``"materials"`` (``roadtwin reconstruct photo-surfaces``: road materials, textures and a
    ``materials.json`` that ``compose --road-textures`` reads).
    ``inputs`` is a dict whose keys and checks are
    :class:`roadtwin_core.apps.reconstruct.SurfaceInputs`,
    :class:`~roadtwin_core.apps.reconstruct.DefectInputs` and, for photos,
    :class:`~roadtwin_core.apps.reconstruct.PhotoSet` (their ``as_dict()`` is what the command
    passes). The command also sets these ``Params`` fields from its options, so the dataclass
    declares them: ``voxel_m``, ``radius_m``, ``align`` (surface); ``disparity_scale``, ``grid_m``
    (defects). Of the result it reads: a surface's ``vertices`` and ``faces`` (a
    :class:`~roadtwin_core.SurfaceModel`), and ``write`` returning the asset's path; for defects,
    ``labels`` (per-pixel instance ids, 0 = road) and ``models`` (:class:`~roadtwin_core.DefectModel`:
    ``name``, ``attributes()``), and ``write`` returning the list of paths written.
    """

    name: str
    description: str
    produces: Literal["surface", "defects", "materials"]
    Params: type

    def run(self, inputs, params) -> Any:
        """Compute the result (nothing written)."""

    def write(self, result, out) -> Any:
        """Write ``result`` under ``out``; return the path(s) written."""


@runtime_checkable
class Merger(Protocol):
    """Merge placed defects into one road segment's mesh and restore its elevation.

    ``params`` is the ``Params`` instance the merger uses; the core configures a copy of the
    registered merger with other values through :func:`configured` (``--param``)."""

    name: str
    description: str
    Params: type
    params: Any

    def merge(self, segment, placements, surface, rules) -> Any:
        """-> :class:`~roadtwin_core.MergedSegment`."""


@runtime_checkable
class LayoutImporter(Protocol):
    """A foreign road network file (e.g. OpenDRIVE) -> :class:`~roadtwin_core.TownLayout`."""

    name: str
    description: str
    Params: type

    def load(self, path, params) -> Any:
        """``params`` is a ``Params`` instance or None (the defaults)."""


@runtime_checkable
class Renderer(Protocol):
    """A labelled triangle scene + cameras -> frames (``roadtwin_core.render`` types).

    ``prepare``, ``check_cameras`` and ``render_events`` are capabilities a renderer may leave to
    :class:`RendererBase`'s defaults."""

    name: str
    description: str
    Params: type

    def render(self, scene, cameras, params, *, look=None) -> Iterator[Any]:
        """Yield one Frame per camera, in order. ``look``: the frame's randomized scene look
        (``roadtwin render --randomize``), None for the stage's own materials."""

    def prepare(self, scene, params) -> Any:
        """Build acceleration structures once; the result is what ``render`` gets as ``scene``."""

    def check_cameras(self, prepared, cameras, params) -> None:
        """Raise RoadtwinError for cameras inside geometry, before anything is written."""

    def render_events(self, scene, cameras, times, params, *, progress=None, threshold: float = 0.2,
                      seed: int = 0) -> tuple[dict, dict] | None:
        """Event-camera output simulated where the frames are (e.g. on the GPU), or None: the
        core then simulates the events from the frames ``render`` yields."""


class RendererBase:
    """Defaults for a renderer's optional capabilities: subclass it and write ``render``."""

    def prepare(self, scene, params):
        return scene

    def check_cameras(self, prepared, cameras, params) -> None:
        return None

    def render_events(self, scene, cameras, times, params, *, progress=None, threshold: float = 0.2,
                      seed: int = 0, **camera):
        return None


@runtime_checkable
class PhysicsBackend(Protocol):
    """Vehicles driving over a road collision mesh -> IMU traces (``roadtwin_core.vehicle``)."""

    name: str
    description: str
    Params: type

    def simulate(self, road_mesh, vehicles, params) -> Any:
        """``vehicles`` is a list of VehicleRun, ``params`` a ``Params`` (SimParams) instance."""


@runtime_checkable
class Planner(Protocol):
    """A grid map -> a path from start to goal with wheel- or body-level collision."""

    name: str
    description: str
    Params: type

    def plan(self, grid, start, goal, vehicle, collision, params, rng) -> Any:
        """-> (N, 3) poses running exactly from start to goal, or None."""


@runtime_checkable
class Exporter(Protocol):
    """A composed town stage -> another tool's format; ``name`` is the format."""

    name: str
    description: str
    suffix: str

    def export(self, stage_path, out_path) -> Path:
        """Write ``out_path`` and return the path written."""


@runtime_checkable
class SurfaceSource(Protocol):
    """``--surface SCHEME:ARG`` elevation; ``name`` is the scheme, ``arg`` what follows the colon."""

    name: str
    description: str

    def load(self, arg, bounds, seed) -> Any:
        """-> :class:`~roadtwin_core.SurfaceModel`."""


@runtime_checkable
class DatasetFormat(Protocol):
    """A dataset layout ``roadtwin render --formats NAME`` writes; ``needs_stereo``: only with
    ``--stereo``. The core's own formats (kitti, mmseg, coco, depth, normal) keep their names."""

    name: str
    description: str
    needs_stereo: bool

    def writer(self, dataset) -> Any:
        """The writer of one render. ``dataset`` is the core's dataset writer (``root``,
        ``classes``, ``palette``, ``intrinsics``, ``instances``, ``categories``). The writer's
        ``add(k, stem, frame, files) -> dict`` writes frame ``k``'s files under ``dataset.root``,
        records their paths in ``files`` and returns extra meta.json fields of the frame;
        ``finish()`` runs once after the last frame."""


@runtime_checkable
class Sensor(Protocol):
    """A sensor model a rig file names by ``type``. ``message`` is what its samples are (imu |
    gnss | image | stereo | points: the drive's writers turn them into ROS 2 messages and rerun
    entities). ``create`` mounts one: the result has ``id``, ``rate_hz``, ``extrinsic`` (4x4, the
    sensor frame in the body frame) and ``sample(state, world) -> dict``; ``state`` is the vehicle
    at ``state.t`` on the drive's clock (``pose_at(t)``, ``velocity_at(t)``,
    ``imu_truth(offset, t0, t1)``), ``world`` the scene's services (``render(cameras)``,
    ``cast(origins, dirs)``, ``class_names``)."""

    name: str
    description: str
    Params: type
    message: str

    def create(self, sensor_id, rate_hz, extrinsic, params) -> Any:
        """-> a mounted sensor."""


PROTOCOLS: dict[str, type] = {
    "defect_types": DefectType, "reconstructors": Reconstructor, "mergers": Merger,
    "layout_importers": LayoutImporter, "renderers": Renderer, "physics_backends": PhysicsBackend,
    "planners": Planner, "exporters": Exporter, "surface_sources": SurfaceSource,
    "dataset_formats": DatasetFormat, "sensors": Sensor,
}

_PRODUCES = ("surface", "defects", "materials")
_MESSAGES = ("imu", "gnss", "image", "stereo", "points")  # what a sensor's samples are (Sensor.message)


def _members(protocol: type) -> tuple[list[str], dict[str, inspect.Signature]]:
    """Data attributes (annotations) and methods (with their signatures) a protocol declares."""
    data = list(getattr(protocol, "__annotations__", {}))
    methods = {n: inspect.signature(f) for n, f in vars(protocol).items()
               if inspect.isfunction(f) and not n.startswith("_")}
    return data, methods


def _callable_like(method, spec: inspect.Signature) -> str:
    """'' if ``method`` accepts what the core passes to ``spec`` (positional and keyword), else why not."""
    try:
        sig = inspect.signature(method)
    except (TypeError, ValueError):
        return ""  # a builtin without a signature: trust it
    wanted = [p for p in spec.parameters.values() if p.name != "self"]
    positional = [None] * sum(p.kind is p.POSITIONAL_OR_KEYWORD for p in wanted)
    keywords = {p.name: None for p in wanted if p.kind is p.KEYWORD_ONLY}
    try:
        sig.bind(*positional, **keywords)
    except TypeError:
        shown = spec.replace(parameters=wanted, return_annotation=inspect.Signature.empty)
        return f"takes {sig.replace(return_annotation=inspect.Signature.empty)}, the contract calls it as {shown}"
    return ""


def check(kind: str, thing: Any) -> list[str]:
    """Every way ``thing`` falls short of the ``kind`` contract (empty: it conforms)."""
    data, methods = _members(PROTOCOLS[kind])
    problems = []
    for attr in data:
        if not hasattr(thing, attr):
            problems.append(f"no attribute {attr!r}")
    for meth, spec in methods.items():
        fn = getattr(thing, meth, None)
        if not callable(fn):
            hint = " (subclass roadtwin_core.contracts.RendererBase for the defaults)" if kind == "renderers" \
                and hasattr(RendererBase, meth) else ""
            problems.append(f"no method {meth}(){hint}")
            continue
        why = _callable_like(fn, spec)
        if why:
            problems.append(f"{meth} {why}")
    name = getattr(thing, "name", None)
    if "name" in data and hasattr(thing, "name") and not (isinstance(name, str) and name):
        problems.append("name must be a non-empty string")
    if "description" in data and hasattr(thing, "description") and not isinstance(thing.description, str):
        problems.append("description must be a string")
    if "Params" in data and hasattr(thing, "Params") and not (
            isinstance(thing.Params, type) and dataclasses.is_dataclass(thing.Params)):
        problems.append("Params must be a dataclass")
    if "produces" in data and hasattr(thing, "produces") and thing.produces not in _PRODUCES:
        problems.append(f"produces must be one of {', '.join(_PRODUCES)}, got {thing.produces!r}")
    if "message" in data and hasattr(thing, "message") and thing.message not in _MESSAGES:
        problems.append(f"message must be one of {', '.join(_MESSAGES)}, got {thing.message!r}")
    if "suffix" in data and hasattr(thing, "suffix") and not (isinstance(thing.suffix, str)
                                                             and thing.suffix.startswith(".")):
        problems.append(f"suffix must be a string starting with '.', got {thing.suffix!r}")
    return problems


def params_class(kind: str, thing: Any) -> type | None:
    """The ``Params`` dataclass of a registered thing, or None for kinds that take no parameters."""
    return thing.Params if "Params" in getattr(PROTOCOLS[kind], "__annotations__", {}) else None


def configured(merger: Any, params: Any) -> Any:
    """A copy of a registered merger that uses ``params`` (the registered one stays as it was)."""
    out = copy.copy(merger)
    out.params = params
    return out
