"""``normal/000000.npy`` (float32 unit normals, camera frame, OpenCV axes) and ``.png`` (RGB view)."""
from __future__ import annotations

from .arrays import FrameArrayWriter
from .images import colorize_normals

__all__ = ["NormalWriter"]


class NormalWriter(FrameArrayWriter):
    name = "normal"

    def view(self, normal):
        return colorize_normals(normal)
