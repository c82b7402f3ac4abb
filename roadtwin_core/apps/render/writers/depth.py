"""``depth/000000.npy`` (float32 z-depth in metres, 0 = no hit) and ``.png`` (colour-mapped view)."""
from __future__ import annotations

from .arrays import FrameArrayWriter
from .images import colorize_scalar

__all__ = ["DepthWriter"]


class DepthWriter(FrameArrayWriter):
    name = "depth"

    def view(self, depth):
        return colorize_scalar(depth, depth > 0, 1.0, 200.0)
