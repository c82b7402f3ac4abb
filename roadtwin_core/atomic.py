"""Write a whole output directory or nothing: build it beside the target, then swap it in."""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

from .errors import RoadtwinError

__all__ = ["atomic_output_dir", "atomic_write_bytes", "make_parent", "remove_stale"]


@contextlib.contextmanager
def atomic_output_dir(outdir: str | Path):
    """Yield a fresh temporary directory; on success it replaces ``outdir`` (an earlier output
    stays intact until then), on any error it is removed and ``outdir`` is untouched."""
    outdir = Path(outdir).resolve()
    if outdir.exists() and not outdir.is_dir():
        raise RoadtwinError(f"{outdir}: exists and is not a directory")
    make_parent(outdir)
    remove_stale(outdir)
    tmp = outdir.parent / f".{outdir.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = outdir.parent / f".{outdir.name}.old-{os.getpid()}"
    if outdir.exists():
        os.replace(outdir, old)
    os.replace(tmp, outdir)
    shutil.rmtree(old, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:        # someone else's process: alive
        return True
    return True


def remove_stale(outdir: Path) -> list[Path]:
    """Remove what crashed runs (``kill -9``, power loss) left beside ``outdir``: its hidden
    ``.NAME.tmp-PID`` / ``.NAME.old-PID`` folders whose process no longer exists. Another live
    run's folders are left alone. A run killed between its two renames leaves the previous
    output only in ``.old-PID``: that is put back first, so nothing the user had is lost."""
    removed = []
    for kind in ("old", "tmp"):
        for path in sorted(outdir.parent.glob(f".{outdir.name}.{kind}-*")):
            pid = path.name.rsplit("-", 1)[-1]
            if not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)):
                continue
            if kind == "old" and not outdir.exists():
                os.replace(path, outdir)
                continue
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


def make_parent(path: str | Path) -> Path:
    """Create the folder an output goes into; a path through a regular file (or any other reason
    the folder cannot be made) is the user's mistake, one line naming the output."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RoadtwinError(f"{path}: cannot create its folder ({exc.strerror or exc})") from None
    if not path.parent.is_dir():
        raise RoadtwinError(f"{path}: its folder {path.parent} is not a directory")
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)
