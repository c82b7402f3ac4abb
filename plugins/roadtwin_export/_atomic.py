"""Write an output file or nothing: build it beside the target, then ``os.replace`` it in."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterator

from roadtwin_core import RoadtwinError


@contextlib.contextmanager
def atomic_files(*targets: Path) -> Iterator[list[Path]]:
    """Yield one temporary path per target, in the target's directory and with its suffix (some
    writers pick the format from it). On success each temporary replaces its target, in the
    order given (so a companion file such as an OBJ's ``.mtl`` is in place before the file that
    names it); on any error every temporary is removed and the targets are untouched."""
    tmps = []
    for target in targets:
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RoadtwinError(f"{target}: cannot create its directory ({exc.strerror})") from None
        if target.is_dir():
            raise RoadtwinError(f"{target}: is a directory")
        tmps.append(target.with_name(f".{target.stem}.tmp-{os.getpid()}{target.suffix}"))
    try:
        yield tmps
        for tmp, target in zip(tmps, targets):
            os.replace(tmp, target)
    except OSError as exc:
        _remove(tmps)
        raise RoadtwinError(f"{targets[0]}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        _remove(tmps)
        raise


def _remove(paths: list[Path]) -> None:
    for p in paths:
        with contextlib.suppress(OSError):
            p.unlink()
