"""Write an output (a directory, one file or several files) or nothing: build it beside the
target under a hidden ``.NAME.tmp-PID`` name, then swap it in with ``os.replace``. What a crashed
run (``kill -9``, power loss) left beside a target is removed by the next run for that target.
The one place roadtwin and its plugins write outputs atomically."""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path
from typing import Iterator

from .errors import RoadtwinError


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


def scratch_dir(target: str | Path, what: str) -> Path:
    """A fresh hidden folder beside ``target`` for work that ends up in it (``what``: a word, e.g.
    ``textures``), named ``.NAME.tmp-WHAT-PID`` so that, like the output's own temporary, what a
    killed run left there is removed by the next run for ``target`` (:func:`remove_stale`)."""
    target = Path(target).resolve()
    make_parent(target)
    path = target.parent / f".{target.name}.tmp-{what}-{os.getpid()}"
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir()
    return path


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:        # someone else's process: alive
        return True
    return True


def remove_stale(target: Path) -> list[Path]:
    """Remove what crashed runs (``kill -9``, power loss) left beside ``target``: its hidden
    ``.NAME.tmp-PID`` / ``.NAME.old-PID`` folders (and ``.STEM.tmp-PID.SUFFIX`` files, see
    :func:`atomic_files`) whose process no longer exists. Another live run's are left alone. A
    run killed between its two renames leaves the previous output only in ``.old-PID``: that is
    put back first, so nothing the user had is lost."""
    target = Path(target)
    removed = []
    litter = [("old", p, p.name.rsplit("-", 1)[-1])
              for p in sorted(target.parent.glob(f".{target.name}.old-*"))]
    litter += [("tmp", p, p.name.rsplit("-", 1)[-1]) for p in sorted(target.parent.glob(f".{target.name}.tmp-*"))]
    if target.suffix:      # a file's temporaries keep its suffix: .STEM.tmp-PID.SUFFIX
        litter += [("tmp", p, p.name[:-len(target.suffix)].rsplit("-", 1)[-1])
                   for p in sorted(target.parent.glob(f".{target.stem}.tmp-*{target.suffix}"))]
    for kind, path, pid in litter:
        if not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)) or not os.path.lexists(path):
            continue
        if kind == "old" and not target.exists():
            os.replace(path, target)
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                path.unlink()
        removed.append(path)
    return removed


def output_path(path: str | Path, kind: str = "file") -> Path:
    """An output ``path`` (``kind`` "file" or "dir") that can be created: not a directory where a
    file goes (or the reverse), and no regular file on the way to it (chmod does not stop root,
    a file in the way does)."""
    path = Path(path)
    if kind == "file" and path.is_dir():
        raise RoadtwinError(f"{path}: is a directory, expected an output file")
    if kind == "dir" and path.exists() and not path.is_dir():
        raise RoadtwinError(f"{path}: exists and is not a directory")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise RoadtwinError(f"{path}: cannot be created, {parent} is not a directory")
    if not os.access(parent, os.W_OK):
        raise RoadtwinError(f"{path}: cannot be created, {parent} is not writable")
    return path


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


def _file_tmp(target: Path) -> Path:
    """The temporary beside a file target: hidden, with the pid (two runs never share one) and
    the target's suffix (writers such as USD and trimesh pick the format from it)."""
    return target.with_name(f".{target.stem}.tmp-{os.getpid()}{target.suffix}")


@contextlib.contextmanager
def atomic_files(*targets: str | Path, parents: bool = True) -> Iterator[list[Path]]:
    """Yield one temporary path per target, in the target's folder and with its suffix. On
    success each temporary replaces its target, in the order given (so a companion file such as
    an OBJ's ``.mtl`` is in place before the file that names it); on any error every temporary
    is removed and the targets are untouched. Crash litter of earlier runs is removed first.
    ``parents=False``: a missing folder is an error instead of being created."""
    targets = tuple(Path(t) for t in targets)
    tmps = []
    for target in targets:
        if parents:
            make_parent(target)
        if target.is_dir():
            raise RoadtwinError(f"{target}: is a directory")
        remove_stale(target)
        tmps.append(_file_tmp(target))
    try:
        yield tmps
        for tmp, target in zip(tmps, targets):
            os.replace(tmp, target)
    except OSError as exc:
        _unlink(tmps)
        raise RoadtwinError(f"{targets[0]}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        _unlink(tmps)
        raise


def atomic_write_bytes(path: str | Path, data: bytes, parents: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_files`)."""
    path = Path(path)
    with atomic_files(path, parents=parents) as (tmp,):
        tmp.write_bytes(data)
    return path


def _unlink(paths: list[Path]) -> None:
    for p in paths:
        with contextlib.suppress(OSError):
            p.unlink()


__all__ = ["atomic_files", "atomic_output_dir", "atomic_write_bytes", "make_parent", "output_path", "remove_stale",
           "scratch_dir"]
