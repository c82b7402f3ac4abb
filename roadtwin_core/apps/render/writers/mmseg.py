"""MMSegmentation layout: ``mmseg/img_dir/train/000000.png`` (a hard link to the image; .jpg when a
sensor model wrote JPEG bytes), ``mmseg/ann_dir/train/000000.png`` (uint8 class ids, 255 ignore)
and ``mmseg/classes.json`` (classes, palette, ignore index)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ....render import IGNORE_INDEX
from .images import link, save_png

__all__ = ["MmsegWriter"]


class MmsegWriter:
    name = "mmseg"
    needs_stereo = False

    def __init__(self, ds) -> None:
        self.ds = ds
        for d in ("mmseg/img_dir/train", "mmseg/ann_dir/train"):
            (ds.root / d).mkdir(parents=True, exist_ok=True)

    def add(self, k: int, stem: str, frame, files: dict) -> dict:
        return self.commit(k, self.write(k, stem, frame, files))

    def commit(self, k: int, state) -> dict:
        return {}

    def write(self, k: int, stem: str, frame, files: dict) -> None:
        """This frame's files (thread-safe: touches nothing shared)."""
        root = self.ds.root
        link(root / files["rgb"], root / "mmseg/img_dir/train" / f"{stem}{Path(files['rgb']).suffix}")
        save_png(root / "mmseg/ann_dir/train" / f"{stem}.png", frame.semantic.astype(np.uint8))
        files["semantic"] = f"mmseg/ann_dir/train/{stem}.png"

    def finish(self) -> None:
        ds = self.ds
        (ds.root / "mmseg/classes.json").write_text(json.dumps(
            {"classes": ds.classes, "palette": ds.palette[:len(ds.classes)].tolist(),
             "ignore_index": IGNORE_INDEX}, indent=1))
