"""Textures made while the town is placed and merged. Generating a texture set costs ~2.5 s of
one core on a cold cache (a new user's first compose), while placement runs on one core and the
other idles: the composer's helper process (:class:`~roadtwin_core.apps.compose.sidecar.Sidecar`, a fresh
interpreter) writes the set into a staging folder beside the output
(:func:`~roadtwin_core.atomic.scratch_dir`: a killed run's is removed by the next), and the
composer moves it next to the stage when it gets there. Same seed, same bytes: the files are exactly what
:func:`write_textures_cached` writes.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from .catalog import MaterialSpec

__all__ = ["TexturePrefetch", "TexturesNow"]


def _write_cached(folder: Path, seed: int) -> dict[str, MaterialSpec]:
    """In the helper process: the generators (scipy.fft and more) are imported there, not here."""
    from .cache import write_textures_cached

    return write_textures_cached(folder, seed)


class TexturePrefetch:
    """``with TexturePrefetch(seed, sidecar, staging) as tex: ... specs = tex.collect(folder)``;
    ``staging``: an empty folder of the caller's. The sidecar is this set's alone: closing stops it
    first (a compose that fails early does not wait for the set), then removes ``staging`` (a
    helper still writing there would put files back into a removed folder).
    """

    def __init__(self, seed: int, sidecar, staging: Path) -> None:
        self._stage = Path(staging)
        self._sidecar = sidecar
        self._ticket = sidecar.submit(_write_cached, self._stage / "textures", seed)
        sidecar.end_when_done()          # generating takes ~250 MB: given back as soon as it is done

    def collect(self, folder: str | Path) -> dict[str, MaterialSpec]:
        """Wait for the set and move it to ``folder`` (which must not exist yet)."""
        specs = self._sidecar.result(self._ticket)
        shutil.move(str(self._stage / "textures"), str(folder))
        return specs

    def close(self) -> None:
        self._sidecar.close()
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
