"""``normal/000000.npy`` (float32 unit normals, camera frame, OpenCV axes) and ``.png`` (RGB view)."""
from __future__ import annotations

import numpy as np

from .images import colorize_normals, save_png

__all__ = ["NormalWriter"]


class NormalWriter:
    name = "normal"
    needs_stereo = False

    def __init__(self, ds) -> None:
        self.ds = ds
        (ds.root / "normal").mkdir(parents=True, exist_ok=True)

    def add(self, k: int, stem: str, frame, files: dict) -> dict:
        root = self.ds.root
        np.save(root / "normal" / f"{stem}.npy", frame.normal.astype(np.float32))
        save_png(root / "normal" / f"{stem}.png", colorize_normals(frame.normal))
        files["normal"] = f"normal/{stem}.npy"
        return {}

    def finish(self) -> None:
        pass
