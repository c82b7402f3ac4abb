"""The dataset formats ``roadtwin render --formats`` knows, by name (as trimesh's exporters: a dict
name -> writer class, one module per format). A writer class has ``name``, ``needs_stereo``,
``__init__(dataset_writer)`` (makes its folders), ``add(k, stem, frame, files) -> dict`` (writes
frame ``k``'s files, records them in ``files``, returns extra meta.json fields of the frame) and
``finish()``. Writers run in this dict's order, whatever order the formats were given in."""
from __future__ import annotations

from typing import Sequence

from ....errors import RoadtwinError
from .coco import CocoWriter
from .depth import DepthWriter
from .kitti import KittiWriter
from .mmseg import MmsegWriter
from .normal import NormalWriter

__all__ = ["FORMATS", "WRITERS", "parse_formats"]

WRITERS: dict[str, type] = {w.name: w for w in (KittiWriter, MmsegWriter, CocoWriter, DepthWriter, NormalWriter)}
FORMATS = tuple(WRITERS)


def parse_formats(text: str | Sequence[str] | None, stereo: bool) -> list[str]:
    """Comma-separated format names -> list; unknown names and stereo layouts without stereo are
    errors. Default: every format that applies."""
    known = ", ".join(WRITERS)
    if text is None:
        names = [n for n, w in WRITERS.items() if stereo or not w.needs_stereo]
    else:
        parts = text.split(",") if isinstance(text, str) else list(text)
        names = [p.strip().lower() for p in parts if p.strip()]
        if not names:
            raise RoadtwinError(f"no output format given (known: {known})")
    unknown = [n for n in names if n not in WRITERS]
    if unknown:
        raise RoadtwinError(f"unknown format {unknown[0]!r} (known: {known})")
    for n in names:
        if WRITERS[n].needs_stereo and not stereo:
            raise RoadtwinError(f"format {n} is a stereo layout: add --stereo")
    return list(dict.fromkeys(names))
