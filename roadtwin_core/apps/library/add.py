"""Adding an asset to a library folder: validated first, copied atomically, rolled back on error.

The payloads are copied first and the interface last, each through a temporary file and
``os.replace`` (:func:`~roadtwin_core.atomic.atomic_files`), so a reader never sees an interface
whose geometry is missing; on any error the copies made so far are removed.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from ...atomic import atomic_files, output_path
from ...errors import RoadtwinError
from ...usd.library import ASSET_SUFFIXES, GEOM_SUFFIX, is_asset_file, read_defect_asset
from .read import AssetInterface, read_interface

__all__ = ["add_asset"]


def add_asset(src: str | Path, folder: str | Path, force: bool = False) -> Path:
    """Validate ``src`` and copy it (with its payloads) into ``folder`` atomically; returns the copy.
    An existing asset of the same name is refused unless ``force``."""
    src, folder = Path(src), Path(folder)
    if not src.is_file():
        raise RoadtwinError(f"{src}: no such file")
    if not is_asset_file(src):   # what list and compose --library would not see
        raise RoadtwinError(f"{src}: not a library asset file (NAME{', NAME'.join(ASSET_SUFFIXES)}; "
                            f"not a {GEOM_SUFFIX} payload, not a hidden file)")
    info = read_interface(src)
    read_defect_asset(src)  # geometry, boundary loop and flags must read too
    payloads = _payload_files(src, info)
    output_path(folder, "dir")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RoadtwinError(f"{folder}: cannot create the library folder ({exc.strerror})") from None
    targets = [(p, folder / p.name) for p in payloads] + [(src, folder / src.name)]
    if src.resolve().parent == folder.resolve():
        raise RoadtwinError(f"{src}: already in library {folder}")
    clash = [t for _, t in targets if t.exists()]
    if clash and not force:
        raise RoadtwinError(f"{folder}: {clash[0].name} already exists (use --force to replace it)")
    _copy_all(src, folder, targets, rollback=not clash)
    return folder / src.name


def _copy_all(src: Path, folder: Path, targets: list[tuple[Path, Path]], rollback: bool) -> None:
    """Copy every (source, target) at once, then read the copy back; if that fails, remove the
    copies (``rollback``: nothing of the same name was there before)."""
    replaced = False
    try:
        with atomic_files(*(t for _, t in targets)) as tmps:
            for tmp, (s, _) in zip(tmps, targets):
                shutil.copyfile(s, tmp)
        replaced = True
        read_defect_asset(folder / src.name)
    except Exception as exc:
        if replaced and rollback:
            for _, t in targets:
                t.unlink(missing_ok=True)
        if isinstance(exc, RoadtwinError):
            raise
        raise RoadtwinError(f"{folder}: cannot add {src.name} ({type(exc).__name__}: {exc})") from None


def _payload_files(src: Path, info: AssetInterface) -> list[Path]:
    """The payload files an asset references, which must lie beside it to be copied along."""
    out = []
    for ap in info.payloads:
        p = (src.parent / ap).resolve() if not Path(ap).is_absolute() else Path(ap)
        if Path(ap).is_absolute() or ".." in Path(ap).parts or "/" in ap.lstrip("./"):
            raise RoadtwinError(f"{src}: payload {ap!r} is not a file beside the asset; cannot copy it into a library")
        if not p.is_file():
            raise RoadtwinError(f"{src}: payload {ap!r} is missing")
        out.append(p)
    return out
