"""``roadtwin compose``: place defects on a layout, merge them into the roads, write and validate
the town stage (``run``), and the helper process beside it that makes textures and draws
``preview.png`` (``sidecar``, ``preview_job``, ``preview``, ``preview_scene``).

What a town stage is built from (defect placement, lane-marking meshes) is framework code in
:mod:`roadtwin_core.town`; this package only orchestrates it.
"""
from .run import ComposeResult, compose

__all__ = ["ComposeResult", "compose"]
