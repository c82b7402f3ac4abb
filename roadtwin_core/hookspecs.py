"""The plugin contract. Every hook receives a ``register`` callback.

A plugin implements any of these with ``@roadtwin_core.hookimpl`` and calls ``register(thing)``
once per thing it provides. A *thing* is a small object (usually a class instance) with a
``name`` (unique within its kind), a one-line ``description`` and, where it takes options, a
``Params`` dataclass built with :func:`roadtwin_core.params.field` so the CLI, the layout file
and ``roadtwin plugins`` can all read and validate them. Registering two things with the same
name is an error that names both plugins.
"""
import pluggy

hookspec = pluggy.HookspecMarker("roadtwin")


@hookspec
def roadtwin_register_defect_types(register):
    """Parametric defect generators (pothole, crack, ...).

    Each registered object has ``name``, ``description``, ``Params`` (dataclass),
    ``sample_params(rng) -> Params`` (a plausible random instance) and
    ``generate(params, rng, name) -> DefectModel``. Same params and rng state give the same model.
    """


@hookspec
def roadtwin_register_reconstructors(register):
    """Sensor data -> SurfaceModel or DefectModel (LiDAR surfaces, stereo defects).

    Each has ``name``, ``description``, ``produces`` ("surface" or "defects") and
    ``reconstruct(inputs, params) -> list`` of models.
    """


@hookspec
def roadtwin_register_mergers(register):
    """Merge placed defects into one road segment mesh and restore elevation.

    Each has ``name``, ``description`` and
    ``merge(segment, placements, surface, rules) -> MergedSegment``.
    """


@hookspec
def roadtwin_register_layout_importers(register):
    """Foreign road networks (e.g. OpenDRIVE) -> TownLayout.

    Each has ``name``, ``suffixes`` (e.g. (".xodr",)) and ``load(path, params) -> TownLayout``.
    """


@hookspec
def roadtwin_register_renderers(register):
    """Town stage -> frames (rgb, semantic, instance, depth, normal, disparity).

    Each has ``name``, ``description`` and ``render(scene, cameras, params) -> Iterator[Frame]``
    (``roadtwin_core.render``: a labelled triangle scene, camera models, RenderParams). Optional:
    ``prepare(scene, params)`` to build acceleration structures once, and
    ``check_cameras(prepared, cameras, params)`` to refuse cameras inside geometry before anything
    is written. Events are simulated by the core from consecutive frames.
    """


@hookspec
def roadtwin_register_physics_backends(register):
    """Vehicles driving over the baked road collision mesh -> IMU traces.

    Each has ``name``, ``description`` and ``simulate(road_mesh, vehicles, params) -> traces``.
    """


@hookspec
def roadtwin_register_planners(register):
    """Grid maps of a town -> paths with wheel-level or body-level collision.

    Each has ``name``, ``description``, ``Params`` and
    ``plan(grid, start, goal, vehicle, collision, params, rng) -> (N, 3) poses or None``, where
    ``grid`` is a ``roadtwin_core.grid.GridMap``, ``collision`` is "wheel" or "body" (checked
    with ``roadtwin_core.planning``), and the path runs exactly from start to goal.
    """


@hookspec
def roadtwin_register_exporters(register):
    """Town stage -> another tool's format (usdz, glb, obj, ply, crg ...).

    Each has ``name`` (the format), ``suffix`` and ``export(stage_path, out_path) -> Path``.
    """


@hookspec
def roadtwin_register_surface_sources(register):
    """Elevation sources for ``--surface SCHEME:ARG`` beyond the core's flat / iso8608 / usd.

    Each has ``name`` (the scheme, e.g. "crg") and ``load(arg, bounds, seed) -> SurfaceModel``
    where ``arg`` is everything after the first colon (a path may contain colons).
    """
