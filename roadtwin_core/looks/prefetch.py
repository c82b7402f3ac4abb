"""Textures made while the town is placed and merged. Generating a texture set costs ~2.5 s of
one core on a cold cache (a new user's first compose), while placement runs on one core and the
other idles: a spawned process (a fresh interpreter: no forked threads, a small footprint) writes
the set into a private staging folder, and the composer moves it next to the stage when it gets
there. Same seed, same bytes: the files are exactly what :func:`write_textures_cached` writes.
"""
from __future__ import annotations

import multiprocessing
import shutil
import tempfile
from pathlib import Path

from .cache import write_textures_cached
from .catalog import MaterialSpec

__all__ = ["TexturePrefetch", "TexturesNow"]


class TexturePrefetch:
    """``with TexturePrefetch(seed) as tex: ... specs = tex.collect(folder)``."""

    def __init__(self, seed: int) -> None:
        self._stage = Path(tempfile.mkdtemp(prefix="roadtwin-textures-"))
        self._pool = multiprocessing.get_context("spawn").Pool(1)
        self._result = self._pool.apply_async(write_textures_cached, (self._stage / "textures", seed))

    def collect(self, folder: str | Path) -> dict[str, MaterialSpec]:
        """Wait for the set and move it to ``folder`` (which must not exist yet)."""
        specs = self._result.get()
        self._pool.terminate()          # its work is done: no idle interpreter through the rest
        self._pool.join()
        shutil.move(str(self._stage / "textures"), str(folder))
        return specs

    def close(self) -> None:
        self._pool.terminate()          # a compose that failed early does not wait for the set
        self._pool.join()
        shutil.rmtree(self._stage, ignore_errors=True)

    def __enter__(self) -> "TexturePrefetch":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class TexturesNow:
    """Another texture writer ``writer(folder, seed) -> specs``, run when collected, in this
    process (tests, custom looks): the same interface as :class:`TexturePrefetch`."""

    def __init__(self, writer, seed: int) -> None:
        self._writer, self._seed = writer, seed

    def collect(self, folder: str | Path) -> dict[str, MaterialSpec]:
        return self._writer(folder, self._seed)

    def close(self) -> None:
        pass

    def __enter__(self) -> "TexturesNow":
        return self

    def __exit__(self, *exc) -> None:
        pass
