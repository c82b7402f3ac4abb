"""A torch ``Dataset`` over a ``roadtwin render`` output directory. torch is imported when the
class is first used, not when this module (or ``roadtwin_core.render``) is imported::

    from roadtwin_core.datasets.render_output import RenderDataset   # imports torch here
    ds = RenderDataset("out/render")
    item = ds[0]   # dict of tensors

Each item holds what the directory has (``meta.json`` lists every frame's files):
``image`` (3,H,W float32 in [0,1]), ``image_right``, ``semantic`` (H,W int64, 255 ignore),
``instance`` (H,W int64, 0 none), ``depth`` (H,W float32 m, 0 none), ``normal`` (3,H,W float32,
camera frame), ``disparity`` (H,W float32 px, 0 invalid) and ``disparity_noc``, plus
``K`` (3,3), ``cam_to_world`` (4,4) and ``index``. ``modalities`` picks a subset; ``transform``
is applied to the item dict.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from ..errors import RoadtwinError
from ._lazy_torch import lazy_classes

__all__ = ["RenderDataset"]

_FILES = {"image": "rgb", "image_right": "rgb_right", "semantic": "semantic", "instance": "instance",
          "depth": "depth", "normal": "normal", "disparity": "disparity", "disparity_noc": "disparity_noc"}


def _read(path: Path, modality: str) -> np.ndarray:
    if path.suffix == ".npy":
        a = np.load(path)
        return np.ascontiguousarray(a.transpose(2, 0, 1)) if modality == "normal" else a
    a = np.asarray(Image.open(path))
    if modality.startswith("image"):
        return np.ascontiguousarray(a[..., :3].transpose(2, 0, 1), dtype=np.float32) / 255.0
    if modality.startswith("disparity"):
        return a.astype(np.float32) / 256.0
    return a.astype(np.int64)


def _make_class():
    import torch
    from torch.utils.data import Dataset

    class RenderDataset(Dataset):
        def __init__(self, root, modalities=None, transform=None):
            self.root = Path(root)
            meta_path = self.root / "meta.json"
            if not meta_path.exists():
                raise RoadtwinError(f"{self.root}: no meta.json (not a roadtwin render output)")
            self.meta = json.loads(meta_path.read_text())
            self.frames = self.meta["frames"]
            have = set.intersection(*(set(f["files"]) for f in self.frames)) if self.frames else set()
            available = [m for m, key in _FILES.items() if key in have]
            if modalities is None:
                modalities = available
            missing = [m for m in modalities if m not in available]
            if missing:
                raise RoadtwinError(f"{self.root}: modality {missing[0]!r} not written (available: {', '.join(available)})")
            self.modalities = list(modalities)
            self.transform = transform
            self.classes = [c["name"] for c in self.meta["classes"]]
            self.K = torch.tensor(self.meta["intrinsics"]["K"], dtype=torch.float32)

        def __len__(self):
            return len(self.frames)

        def __getitem__(self, i):
            f = self.frames[i]
            item = {m: torch.from_numpy(_read(self.root / f["files"][_FILES[m]], m)) for m in self.modalities}
            item["K"] = self.K.clone()
            item["cam_to_world"] = torch.tensor(f["cam_to_world"], dtype=torch.float32)
            item["index"] = f["index"]
            return self.transform(item) if self.transform else item

    return RenderDataset


__getattr__ = lazy_classes(__name__, {"RenderDataset": _make_class})
