"""Checks where USD comes in: every file a command reads as a stage, layout or library asset
passes here first, so bad input is one line naming the file (and prim) instead of a pxr
traceback, a page of C++ warnings or a MemoryError much later.

- :func:`open_stage`: the file exists, is a regular non-empty file with a USD suffix, parses,
  and composes without errors (unresolvable sublayers, references and payloads, sublayer
  cycles: ``Usd.Stage.GetCompositionErrors``). USD's own diagnostics during the open are
  collected (``UsdUtils.CoalescingDiagnosticDelegate``) rather than printed, because the CLI
  promises one line on stderr; the first one becomes the message.
- :func:`check_points`: finite coordinates within :data:`MAX_COORD_M` of the origin.
- :class:`FaceBudget`: triangles per mesh and per file within a budget, so a 10 km segment of
  1 mm triangles is refused by name before the merger or a renderer tries to hold it. The
  budgets are environment variables (``ROADTWIN_MAX_MESH_FACES``, ``ROADTWIN_MAX_FACES``)
  because a real city may legitimately need more; the message says which one to raise.

Up axis and units of layouts stay in :func:`.layout_io.open_layout_stage` (refused unless Z-up
meters); composed stages written by other tools are converted by their readers.
"""
from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path
from typing import Iterator

import numpy as np
from pxr import Sdf, Tf, Usd, UsdUtils

from ..errors import RoadtwinError

#: Beyond this distance from the origin (metres) a coordinate is not a road: float32 points
#: keep only ~0.5 m of precision at 1e7 m, and grids over such extents cannot be allocated.
MAX_COORD_M = 1.0e7
#: Default budgets (triangles after fan triangulation). The largest shipped layout, town01,
#: has about 10k triangles per segment; a composed town of 646 segments about 2 million.
DEFAULT_MESH_FACES = 2_000_000
DEFAULT_TOTAL_FACES = 20_000_000


def usd_file(path: Path, what: str = "USD file") -> Path:
    """``path`` is a regular, non-empty file whose suffix USD knows, or one line saying why not."""
    path = Path(path)
    if not path.exists():
        raise RoadtwinError(f"{path}: no such file")
    if path.is_dir():
        raise RoadtwinError(f"{path}: is a directory, expected a {what}")
    if not path.is_file():
        raise RoadtwinError(f"{path}: not a regular file, expected a {what}")
    if Sdf.FileFormat.FindByExtension(path.suffix.lstrip(".").lower() or "-") is None:
        raise RoadtwinError(f"{path}: not a USD file (suffix {path.suffix or 'none'}; expected .usd, .usda, .usdc or .usdz)")
    if path.stat().st_size == 0:
        raise RoadtwinError(f"{path}: empty file, expected a {what}")
    return path


@contextlib.contextmanager
def quiet_usd() -> Iterator[list[str]]:
    """Collect USD's warnings and status messages instead of letting them print to stderr;
    yields the list the messages are appended to when the block ends."""
    messages: list[str] = []
    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    try:
        yield messages
    finally:
        messages.extend(d.commentary for d in delegate.TakeUncoalescedDiagnostics())
        del delegate


def first_error(exc: BaseException) -> str:
    """The first quoted message of a ``Tf.ErrorException`` (its text is several C++ lines)."""
    text = str(exc)
    m = re.search(r" : '(.*?)'\s*(?:\n|$)", text, re.S)
    line = m.group(1) if m else (text.strip().splitlines()[0] if text.strip() else type(exc).__name__)
    return " ".join(line.split())


def open_stage(path: str | Path, what: str = "USD stage", load=Usd.Stage.LoadAll,
               default_prim: bool = True) -> Usd.Stage:
    """Open ``path`` as a stage that composes cleanly, or raise one RoadtwinError naming it."""
    path = usd_file(Path(path), what)
    with quiet_usd():
        try:
            stage = Usd.Stage.Open(str(path), load)
        except Tf.ErrorException as exc:
            raise RoadtwinError(f"{path}: not a USD file that can be read as a {what} ({first_error(exc)})") from None
        if stage is None:
            raise RoadtwinError(f"{path}: not a readable {what}")
        check_composition(stage, path)
    if default_prim and not stage.GetDefaultPrim():
        raise RoadtwinError(f"{path}: has no defaultPrim (or it names a prim that does not exist)")
    return stage


def check_composition(stage: Usd.Stage, path: str | Path) -> None:
    """Unresolvable sublayers, references or payloads and sublayer cycles are errors, not the
    silently missing geometry USD would otherwise compose."""
    errors = list(stage.GetCompositionErrors())
    if not errors:
        return
    message = " ".join(str(errors[0]).split())
    more = f" (and {len(errors) - 1} more composition error(s))" if len(errors) > 1 else ""
    raise RoadtwinError(f"{path}: {message}{more}")


def check_points(points: np.ndarray, where: str) -> None:
    """Finite coordinates within :data:`MAX_COORD_M` metres of the origin."""
    if len(points) == 0:
        return
    if not np.isfinite(points).all():
        bad = int(np.argwhere(~np.isfinite(points))[0][0])
        raise RoadtwinError(f"{where}: point {bad} is NaN or infinite")
    far = float(np.abs(points).max())
    if far > MAX_COORD_M:
        raise RoadtwinError(f"{where}: a coordinate is {far:.3g} m from the origin (more than {MAX_COORD_M:.0e} m); "
                            "move the data near the origin")


def _budget(name: str, default: int) -> int:
    raw = os.environ.get(name, "")
    try:
        value = int(raw) if raw else default
    except ValueError:
        raise RoadtwinError(f"{name}={raw!r}: must be a whole number of triangles") from None
    if value <= 0:
        raise RoadtwinError(f"{name}={raw!r}: must be positive")
    return value


class FaceBudget:
    """Triangles per mesh and per file within budget: an absurdly fine mesh is refused by name
    before anything allocates per-triangle work for it."""

    def __init__(self, source: str | Path) -> None:
        self.source = str(source)
        self.per_mesh = _budget("ROADTWIN_MAX_MESH_FACES", DEFAULT_MESH_FACES)
        self.total = _budget("ROADTWIN_MAX_FACES", DEFAULT_TOTAL_FACES)
        self.used = 0

    def take(self, n_faces: int, where: str) -> None:
        if n_faces > self.per_mesh:
            raise RoadtwinError(f"{where}: {n_faces:,} triangles, more than the {self.per_mesh:,} allowed per mesh "
                                "(coarsen it, or raise ROADTWIN_MAX_MESH_FACES)")
        self.used += n_faces
        if self.used > self.total:
            raise RoadtwinError(f"{self.source}: more than {self.total:,} triangles in all (coarsen the meshes, "
                                "or raise ROADTWIN_MAX_FACES)")
