"""The shape the depth and normal writers share: one array per frame as ``NAME/000000.npy``
(float32) and a colour view of it as ``NAME/000000.png``; a subclass names the frame field
(``name``) and draws the view."""
from __future__ import annotations

import numpy as np

from .images import save_png

__all__ = ["FrameArrayWriter"]


class FrameArrayWriter:
    name = ""
    needs_stereo = False

    def __init__(self, ds) -> None:
        self.ds = ds
        (ds.root / self.name).mkdir(parents=True, exist_ok=True)

    def view(self, array: np.ndarray) -> np.ndarray:     # pragma: no cover - interface
        raise NotImplementedError

    def add(self, k: int, stem: str, frame, files: dict) -> dict:
        return self.commit(k, self.write(k, stem, frame, files))

    def write(self, k: int, stem: str, frame, files: dict) -> None:
        """This frame's files (thread-safe: touches nothing shared); ``commit`` records nothing."""
        array = getattr(frame, self.name)
        folder = self.ds.root / self.name
        np.save(folder / f"{stem}.npy", array.astype(np.float32))
        save_png(folder / f"{stem}.png", self.view(array))
        files[self.name] = f"{self.name}/{stem}.npy"

    def commit(self, k: int, state) -> dict:
        return {}

    def finish(self) -> None:
        """Nothing is written per dataset."""
