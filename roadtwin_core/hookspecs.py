"""The plugin hooks. Every hook receives a ``register`` callback.

A plugin implements any of these with ``@roadtwin_core.hookimpl`` and calls ``register(thing)``
once per thing it provides. What a *thing* of each kind must have is written as a
``typing.Protocol`` in :mod:`roadtwin_core.contracts` (named in each hook below); every kind has a
``name`` (unique within its kind) and a one-line ``description``, and most a ``Params``
dataclass built with :func:`roadtwin_core.params.field` so ``--param key=value``, the layout file
and ``roadtwin plugins --params NAME`` can all read and validate them. The plugin manager checks
each thing against its protocol when it is registered: one that does not conform, or a second
thing with a name already taken, is reported by plugin name and the others keep working.
"""
import pluggy

hookspec = pluggy.HookspecMarker("roadtwin")


@hookspec
def roadtwin_register_defect_types(register):
    """Parametric defect generators (pothole, crack, ...): :class:`~roadtwin_core.contracts.DefectType`."""


@hookspec
def roadtwin_register_reconstructors(register):
    """Sensor data -> a SurfaceModel or DefectModels (LiDAR surfaces, stereo defects):
    :class:`~roadtwin_core.contracts.Reconstructor` (``run(inputs, params)``, then
    ``write(result, out)``)."""


@hookspec
def roadtwin_register_mergers(register):
    """Merge placed defects into one road segment mesh and restore elevation:
    :class:`~roadtwin_core.contracts.Merger`."""


@hookspec
def roadtwin_register_layout_importers(register):
    """Foreign road networks (e.g. OpenDRIVE) -> TownLayout: :class:`~roadtwin_core.contracts.LayoutImporter`."""


@hookspec
def roadtwin_register_renderers(register):
    """Town stage -> frames (rgb, semantic, instance, depth, normal, disparity):
    :class:`~roadtwin_core.contracts.Renderer`; subclass
    :class:`~roadtwin_core.contracts.RendererBase` for the optional capabilities' defaults."""


@hookspec
def roadtwin_register_physics_backends(register):
    """Vehicles driving over the baked road collision mesh -> IMU traces:
    :class:`~roadtwin_core.contracts.PhysicsBackend`."""


@hookspec
def roadtwin_register_planners(register):
    """Grid maps of a town -> paths with wheel-level or body-level collision:
    :class:`~roadtwin_core.contracts.Planner`."""


@hookspec
def roadtwin_register_exporters(register):
    """Town stage -> another tool's format (usdz, glb, obj, ply, crg ...):
    :class:`~roadtwin_core.contracts.Exporter`."""


@hookspec
def roadtwin_register_surface_sources(register):
    """Elevation sources for ``--surface SCHEME:ARG`` beyond the core's flat / iso8608 / usd:
    :class:`~roadtwin_core.contracts.SurfaceSource`."""


@hookspec
def roadtwin_register_dataset_formats(register):
    """Dataset layouts for ``roadtwin render --formats NAME`` beyond the core's kitti / mmseg /
    coco / depth / normal: :class:`~roadtwin_core.contracts.DatasetFormat`."""


@hookspec
def roadtwin_register_sensors(register):
    """Sensor models a drive's rig mounts on the vehicle (IMU, GNSS, cameras, LiDAR ...):
    :class:`~roadtwin_core.contracts.Sensor`."""
