"""Many drives on one town through the executors (issue 20 item 6): one route per task, each
drive's output in its own subfolder ``route_000``, ``route_001``, ... of the output folder, and
``drives.json`` listing them.

Like ``render`` (docs/architecture.md, "Executors"): everything that can fail on bad input is
checked here first (every route on the road, naming the route), then each task drives one route
with :func:`~.run.run_drive`; a drive depends only on its route and the options, so every
executor writes the same bytes. The town is loaded once per process: the main process fills the
cache that the serial executor uses and forked local workers inherit; a Ray worker loads it on
its first task. The tasks write into the output's temporary folder, so a Ray cluster must share
that filesystem (a local cluster does); the whole output appears at once or not at all.
"""
from __future__ import annotations

import dataclasses
import json
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ...atomic import atomic_output_dir
from ...errors import RoadtwinError
from ...executors import make_executor
from ...plugins import get_plugin_manager
from .rig import load_rig, override, select
from .run import DriveOptions, check_options, load_stage, prepare_drive, run_drive

__all__ = ["DriveTask", "read_routes_file", "run_drives"]

_LOADED: dict[str, dict] = {}          # token -> load_stage(...) of the drives this process serves


@dataclass(frozen=True)
class DriveContext:
    """What every task shares (shipped once per worker): small and picklable."""

    token: str
    stage: str
    options: DriveOptions
    root: str                           # the output's temporary folder


@dataclass(frozen=True)
class DriveTask:
    index: int
    route: str

    @property
    def folder(self) -> str:
        return f"route_{self.index:03d}"


def read_routes_file(path: Path) -> list[str]:
    """One route a line (``auto``, ``lane:ID,...`` or a route file, relative to this file's
    folder); blank lines and ``#`` comments skipped."""
    path = Path(path)
    if not path.is_file():
        raise RoadtwinError(f"--routes {path}: no such file")
    routes = []
    for line in path.read_text(encoding="utf-8").splitlines():
        spec = line.split("#", 1)[0].strip()
        if not spec:
            continue
        if spec != "auto" and not spec.startswith("lane:") and not Path(spec).is_absolute():
            spec = str(path.parent / spec)
        routes.append(spec)
    if not routes:
        raise RoadtwinError(f"--routes {path}: no routes in it")
    return routes


def _loaded(ctx: DriveContext, needs_render: bool) -> dict:
    hit = _LOADED.get(ctx.token)
    if hit is None:
        _LOADED.clear()                 # one set of drives at a time per process
        hit = _LOADED[ctx.token] = load_stage(Path(ctx.stage), needs_render)
    return hit


def drive_task(ctx: DriveContext, task: DriveTask) -> dict:
    """Drive one route into its subfolder (module-level, so process pools and Ray can ship it);
    returns its summary without the trajectory."""
    opt = dataclasses.replace(ctx.options, route=task.route)
    pm = get_plugin_manager()
    needs_render = _needs_render(opt, pm)
    res = run_drive(Path(ctx.stage), Path(ctx.root) / task.folder, opt, pm=pm, loaded=_loaded(ctx, needs_render))
    res.pop("trajectory", None)
    return res


def _absolute(opt: DriveOptions) -> DriveOptions:
    """The options with every file path absolute (a Ray worker may run in another folder)."""
    def fix(p):
        return Path(p).resolve() if p is not None else None
    return dataclasses.replace(opt, rig=fix(opt.rig), vehicle=fix(opt.vehicle), speed_profile=fix(opt.speed_profile))


def _absolute_route(route: str) -> str:
    return str(Path(route).resolve()) if route != "auto" and not route.startswith("lane:") else route


def _needs_render(opt: DriveOptions, pm) -> bool:
    rig_name, specs = load_rig(opt.rig)
    chosen = override(select(specs, opt.sensors, rig_name), opt.sensor_params, rig_name)
    return any(pm.get("sensors", s.type).message in ("image", "stereo") for s in chosen)


def run_drives(stage: Path, out: Path, opt: DriveOptions, routes: list[str], executor: str = "local",
               workers: int | None = None, ray_address: str | None = None,
               progress: Callable[[int, int], None] | None = None) -> dict:
    """Drive every route of ``routes`` on ``executor`` into ``out/route_NNN`` (``out`` replaced
    whole, or left as it was on an error) and write ``out/drives.json``."""
    if not routes:
        raise RoadtwinError("drive: no routes given")
    if workers is not None and workers < 1:
        raise RoadtwinError(f"--workers must be >= 1, got {workers}")
    check_options(opt)
    runner = make_executor(executor, ray_address, workers)
    stage, opt = Path(stage).resolve(), _absolute(opt)
    routes = [_absolute_route(r) for r in routes]
    pm = get_plugin_manager()
    if not stage.is_file():
        raise RoadtwinError(f"{stage}: no such file")
    loaded = load_stage(stage, _needs_render(opt, pm))
    for k, route in enumerate(routes):
        try:
            prepare_drive(stage, dataclasses.replace(opt, route=route), pm, loaded)
        except RoadtwinError as exc:
            raise RoadtwinError(f"route {k} ({route}): {exc}") from None
    loaded.pop("world", None)           # each process prepares its own renderer scene
    tasks = [DriveTask(k, r) for k, r in enumerate(routes)]
    listing = []
    token = uuid.uuid4().hex
    results = []
    with atomic_output_dir(out) as tmp:
        ctx = DriveContext(token, str(stage), opt, str(tmp))
        _LOADED.clear()
        _LOADED[token] = loaded
        try:
            for res in runner.imap(drive_task, ctx, tasks, progress):
                results.append(res)
        finally:
            _LOADED.pop(token, None)
        listing = [{"folder": t.folder, "route": t.route, "source": r["route"], "driven_m": r["driven_m"],
                    "duration_s": r["duration_s"], "contacts": r["contacts"],
                    "samples": {k: v["samples"] for k, v in r["sensors"].items()}} for t, r in zip(tasks, results)]
        (tmp / "drives.json").write_text(json.dumps({"stage": str(stage), "drives": listing}, indent=2,
                                                    default=float))
    return {"executor": runner.name, "drives": listing, "results": results}
