"""Plugin manager: built-ins and third-party plugins alike come from the ``roadtwin``
entry-point group. A plugin that fails to import (or whose hook raises) is recorded by name and
the rest keep working; so is a registered object that does not meet its kind's contract
(:mod:`roadtwin_core.contracts`). ``ROADTWIN_PLUGINS=a,b`` limits loading to an allow-list.
"""
from __future__ import annotations

import importlib.metadata
import os
from dataclasses import dataclass, field
from typing import Any, Collection

import pluggy

from . import contracts, hookspecs
from .errors import RoadtwinError

ENTRY_POINT_GROUP = "roadtwin"
ALLOW_ENV = "ROADTWIN_PLUGINS"
KINDS = ("defect_types", "reconstructors", "mergers", "layout_importers", "renderers",
         "physics_backends", "planners", "exporters", "surface_sources", "dataset_formats", "sensors")

hookimpl = pluggy.HookimplMarker("roadtwin")


@dataclass
class PluginInfo:
    name: str
    version: str = ""
    registered: dict[str, list[str]] = field(default_factory=dict)
    error: str = ""


class PluginManager:
    """Loads plugins once and answers "give me the merger called X" by name."""

    def __init__(self, load_entry_points: bool = True, only: Collection[str] | None = None) -> None:
        """``only``: load just these entry points (within ``ROADTWIN_PLUGINS``), e.g. the one plugin
        a helper process needs (:meth:`provider`), not the imports of all of them."""
        self.pm = pluggy.PluginManager("roadtwin")
        self.pm.add_hookspecs(hookspecs)
        self.info: dict[str, PluginInfo] = {}
        self._registries: dict[str, dict[str, Any]] = {}
        if load_entry_points:
            self._load_entry_points(only)

    def _load_entry_points(self, only: Collection[str] | None = None) -> None:
        allow = os.environ.get(ALLOW_ENV)
        allowed = {a.strip() for a in allow.split(",") if a.strip()} if allow is not None else None
        for ep in sorted(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
            if (allowed is not None and ep.name not in allowed) or (only is not None and ep.name not in only):
                continue
            version = ep.dist.version if ep.dist is not None else ""
            info = self.info.setdefault(ep.name, PluginInfo(ep.name, version))
            try:
                module = ep.load()
                self.pm.register(module, name=ep.name)
            except Exception as exc:  # a broken plugin must not take the others down
                _add_error(info, f"{type(exc).__name__}: {exc}")

    def register(self, plugin: Any, name: str, version: str = "") -> None:
        """Register a plugin object directly (tests, notebooks)."""
        self.pm.register(plugin, name=name)
        self.info.setdefault(name, PluginInfo(name, version))
        self._registries.clear()

    def registry(self, kind: str) -> dict[str, Any]:
        """All things of a kind, by name; calls each plugin's hook separately."""
        if kind not in KINDS:
            raise ValueError(f"unknown kind {kind!r}")
        if kind in self._registries:
            return self._registries[kind]
        things: dict[str, Any] = {}
        owners: dict[str, str] = {}
        hook = getattr(self.pm.hook, f"roadtwin_register_{kind}")
        for impl in reversed(hook.get_hookimpls()):
            plugin_name = impl.plugin_name
            info = self.info.setdefault(plugin_name, PluginInfo(plugin_name))
            # Recomputed after register() cleared the cache: start this kind's list afresh.
            info.registered.pop(kind, None)
            mine: list[Any] = []
            try:
                impl.function(register=mine.append)
            except Exception as exc:
                _add_error(info, f"{kind}: {type(exc).__name__}: {exc}")
                continue
            for thing in mine:
                name = getattr(thing, "name", None)
                if not name:
                    _add_error(info, f"{kind}: registered an object without a name")
                    continue
                problems = contracts.check(kind, thing)
                if problems:
                    _add_error(info, f"{kind}: {name!r} does not meet the contract: {', '.join(problems)}")
                    continue
                if name in things:
                    _add_error(info, f"{kind}: {name!r} already registered by plugin {owners[name]!r}")
                    continue
                things[name] = thing
                owners[name] = plugin_name
                info.registered.setdefault(kind, []).append(name)
        self._registries[kind] = things
        return things

    def get(self, kind: str, name: str) -> Any:
        things = self.registry(kind)
        if name not in things:
            known = ", ".join(sorted(things)) or "none"
            label = kind.replace("_", " ").rstrip("s")
            raise RoadtwinError(f"unknown {label} {name!r} (known: {known})")
        return things[name]

    def provider(self, kind: str, name: str) -> str | None:
        """The plugin (entry point) that registered the ``kind`` called ``name``, if any."""
        self.registry(kind)
        return next((p for p, info in self.info.items() if name in info.registered.get(kind, ())), None)

    def load_all(self) -> dict[str, PluginInfo]:
        """Ask every hook once so ``info`` lists everything registered."""
        for kind in KINDS:
            self.registry(kind)
        return self.info


def _add_error(info: PluginInfo, message: str) -> None:
    """Keep every distinct problem of a plugin (``"; "``-joined), not just the last one."""
    if message not in info.error.split("; "):
        info.error = f"{info.error}; {message}" if info.error else message


_manager: PluginManager | None = None


def get_plugin_manager() -> PluginManager:
    global _manager
    if _manager is None:
        _manager = PluginManager()
    return _manager


def reset_plugin_manager() -> None:
    """Forget loaded plugins (after changing ROADTWIN_PLUGINS, in tests)."""
    global _manager
    _manager = None
