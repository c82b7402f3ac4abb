"""``roadtwin compose``: place defects on a layout, merge them into the roads, write and validate
the town stage (``run``), and the helper process beside it that makes textures and draws
``preview.png`` (``sidecar``, ``preview_job``, ``preview``, ``preview_scene``).

What a town stage is built from (defect placement, lane-marking meshes) is framework code in
:mod:`roadtwin_core.town`; this package only orchestrates it.

``compose`` and ``ComposeResult`` load on first use (PEP 562): the helper processes import
``sidecar`` (and the preview's modules) through this package, and importing ``run`` here would
make each of them load the whole composer (USD, scipy, the merger's modules) before its first job.
"""
import importlib

__all__ = ["ComposeResult", "compose"]


def __getattr__(name: str):
    if name in __all__:
        value = getattr(importlib.import_module(".run", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
