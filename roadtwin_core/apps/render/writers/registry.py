"""The dataset formats ``roadtwin render --formats`` knows, by name (as trimesh's exporters: a dict
name -> writer class, one module per format). A writer class has ``name``, ``needs_stereo``,
``__init__(dataset_writer)`` (makes its folders), ``add(k, stem, frame, files) -> dict`` (writes
frame ``k``'s files, records them in ``files``, returns extra meta.json fields of the frame) and
``finish()``. Writers run in this dict's order, whatever order the formats were given in. Plugins
add formats through the ``dataset_formats`` hook (:func:`available_formats`). A writer may split
``add`` in two: ``write(k, stem, frame, files) -> state`` (files only, safe on any thread or
worker process) and ``commit(k, state) -> dict`` (in frame order); the core's writers do, so a
GPU render writes frames in parallel (``DatasetWriter.write`` / ``commit``); a writer with ``add``
alone is called at commit, in order."""
from __future__ import annotations

from typing import Any, Sequence

from ....errors import RoadtwinError
from .coco import CocoWriter
from .depth import DepthWriter
from .kitti import KittiWriter
from .mmseg import MmsegWriter
from .normal import NormalWriter

__all__ = ["FORMATS", "WRITERS", "available_formats", "parse_formats"]

WRITERS: dict[str, type] = {w.name: w for w in (KittiWriter, MmsegWriter, CocoWriter, DepthWriter, NormalWriter)}
FORMATS = tuple(WRITERS)


class _PluginFormat:
    """A plugin's :class:`~roadtwin_core.contracts.DatasetFormat` as this registry's writer classes
    are used: ``needs_stereo``, and called with the dataset writer to make the render's writer."""

    def __init__(self, fmt: Any) -> None:
        self.fmt, self.name, self.needs_stereo = fmt, fmt.name, bool(fmt.needs_stereo)

    def __call__(self, dataset) -> Any:
        return self.fmt.writer(dataset)


def available_formats(plugin_formats: dict[str, Any] | None = None) -> dict[str, Any]:
    """The core's formats, then the plugins' (name -> ``DatasetFormat``), in that order; a plugin
    format named like a core one does not replace it."""
    out = dict(WRITERS)
    for name, fmt in (plugin_formats or {}).items():
        out.setdefault(name.lower(), _PluginFormat(fmt))       # --formats names are matched in lower case
    return out


def parse_formats(text: str | Sequence[str] | None, stereo: bool, available: dict[str, Any] | None = None) -> list[str]:
    """Comma-separated format names -> list; unknown names and stereo layouts without stereo are
    errors. Default: every format that applies. ``available``: :func:`available_formats`
    (default: the core's). Plugin formats are written only when named."""
    formats = available if available is not None else WRITERS
    known = ", ".join(formats)
    if text is None:
        names = [n for n, w in WRITERS.items() if stereo or not w.needs_stereo]
    else:
        parts = text.split(",") if isinstance(text, str) else list(text)
        names = [p.strip().lower() for p in parts if p.strip()]
        if not names:
            raise RoadtwinError(f"no output format given (known: {known})")
    unknown = [n for n in names if n not in formats]
    if unknown:
        raise RoadtwinError(f"unknown format {unknown[0]!r} (known: {known})")
    for n in names:
        if formats[n].needs_stereo and not stereo:
            raise RoadtwinError(f"format {n} is a stereo layout: add --stereo")
    return list(dict.fromkeys(names))
