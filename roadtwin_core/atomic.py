"""Write a whole output directory or nothing: build it beside the target, then swap it in."""
from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

from .errors import RoadtwinError


@contextlib.contextmanager
def atomic_output_dir(outdir: str | Path):
    """Yield a fresh temporary directory; on success it replaces ``outdir`` (an earlier output
    stays intact until then), on any error it is removed and ``outdir`` is untouched."""
    outdir = Path(outdir).resolve()
    if outdir.exists() and not outdir.is_dir():
        raise RoadtwinError(f"{outdir}: exists and is not a directory")
    outdir.parent.mkdir(parents=True, exist_ok=True)
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


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)
