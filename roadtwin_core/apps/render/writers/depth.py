"""``depth/000000.npy`` (float32 z-depth in metres, 0 = no hit) and ``.png`` (colour-mapped view)."""
from __future__ import annotations

import numpy as np

from .images import colorize_scalar, save_png

__all__ = ["DepthWriter"]


class DepthWriter:
    name = "depth"
    needs_stereo = False

    def __init__(self, ds) -> None:
        self.ds = ds
        (ds.root / "depth").mkdir(parents=True, exist_ok=True)

    def add(self, k: int, stem: str, frame, files: dict) -> dict:
        root = self.ds.root
        np.save(root / "depth" / f"{stem}.npy", frame.depth.astype(np.float32))
        save_png(root / "depth" / f"{stem}.png", colorize_scalar(frame.depth, frame.depth > 0, 1.0, 200.0))
        files["depth"] = f"depth/{stem}.npy"
        return {}

    def finish(self) -> None:
        pass
