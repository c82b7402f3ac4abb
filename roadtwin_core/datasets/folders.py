"""Segmentation dataset folders (real or synthetic): pair images with label images, check them,
load them, and a torch ``Dataset`` over them.

Two layouts are read, so real and rendered frames go through the same code::

    FOLDER/images/<stem>.jpg|.jpeg|.png   FOLDER/labels/<stem>.png          (road_defects_br)
    FOLDER/img_dir/<split>/<stem>.png     FOLDER/ann_dir/<split>/<stem>.png (MMSeg; also
                                          FOLDER/mmseg/..., i.e. a ``roadtwin render`` output)

Labels are single-channel PNGs of class ids ``0 .. num_classes-1``, 255 = ignore. Whatever does
not fit (a missing folder, an empty one, images and labels that do not pair up by stem, a label
value outside the classes, a label of another size than its image) is a
:class:`RoadtwinError` of one line naming the folder or file. numpy + Pillow; torch is
imported when :class:`SegmentationFolder` is first used.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image

from ..errors import RoadtwinError
from ..render import IGNORE_INDEX
from ._lazy_torch import lazy_classes

__all__ = ["IGNORE_INDEX", "IMAGE_SUFFIXES", "Sample", "SegmentationFolder", "find_pairs", "load_folder", "read_image",
           "read_label", "read_sample"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class Sample:
    stem: str          # unique within the folder ("<split>/<stem>" in MMSeg layouts)
    image: Path
    label: Path


def _files(folder: Path, suffixes: Sequence[str]) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for p in sorted(folder.iterdir()):
        if p.is_file() and p.suffix.lower() in suffixes:
            if p.stem in out:
                raise RoadtwinError(f"{folder}: two files for {p.stem!r} ({out[p.stem].name}, {p.name})")
            out[p.stem] = p
    return out


def _pair(folder: Path, img_dir: Path, lab_dir: Path, prefix: str = "") -> list[Sample]:
    images = _files(img_dir, IMAGE_SUFFIXES)
    labels = _files(lab_dir, (".png",))
    lonely_images = sorted(set(images) - set(labels))
    lonely_labels = sorted(set(labels) - set(images))
    if lonely_images or lonely_labels:
        parts = []
        if lonely_images:
            parts.append(f"{len(lonely_images)} image(s) without a label (e.g. {images[lonely_images[0]].relative_to(folder)})")
        if lonely_labels:
            parts.append(f"{len(lonely_labels)} label(s) without an image (e.g. {labels[lonely_labels[0]].relative_to(folder)})")
        raise RoadtwinError(f"{folder}: images and labels do not pair up by name: {'; '.join(parts)}")
    return [Sample(prefix + s, images[s], labels[s]) for s in sorted(images)]


def find_pairs(folder: str | Path) -> list[Sample]:
    """Image/label pairs of a dataset folder (either layout), sorted by stem."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RoadtwinError(f"{folder}: no such dataset folder")
    if (folder / "mmseg").is_dir() and not (folder / "labels").is_dir():
        # a ``roadtwin render`` output: images/ holds RGB previews of every format, the labelled
        # pairs are in mmseg/
        return find_pairs(folder / "mmseg")
    if (folder / "images").is_dir() or (folder / "labels").is_dir():
        for sub in ("images", "labels"):
            if not (folder / sub).is_dir():
                raise RoadtwinError(f"{folder}: has no {sub}/ folder beside its "
                                    f"{'labels' if sub == 'images' else 'images'}/")
        samples = _pair(folder, folder / "images", folder / "labels")
    elif (folder / "img_dir").is_dir() and (folder / "ann_dir").is_dir():
        splits = sorted(p.name for p in (folder / "img_dir").iterdir() if p.is_dir())
        splits += sorted(p.name for p in (folder / "ann_dir").iterdir() if p.is_dir() and p.name not in splits)
        samples = []
        for split in splits:
            i, a = folder / "img_dir" / split, folder / "ann_dir" / split
            if not (i.is_dir() and a.is_dir()):
                raise RoadtwinError(f"{folder}: split {split!r} is in only one of img_dir/ and ann_dir/")
            samples += _pair(folder, i, a, prefix=f"{split}/")
    else:
        raise RoadtwinError(f"{folder}: not a dataset folder (expected images/ + labels/, "
                            f"or MMSeg img_dir/ + ann_dir/)")
    if not samples:
        raise RoadtwinError(f"{folder}: empty dataset folder (no images)")
    return samples


def read_image(path: str | Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB."""
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except OSError as exc:
        raise RoadtwinError(f"{path}: not a readable image ({exc})") from None


def read_label(path: str | Path, num_classes: int, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) uint8 class ids, checked: every value < ``num_classes`` or 255 (ignore)."""
    try:
        with Image.open(path) as im:
            if im.mode not in ("L", "P", "I", "I;16"):
                raise RoadtwinError(f"{path}: label image has mode {im.mode}, expected one channel of class ids")
            a = np.asarray(im)
    except OSError as exc:
        raise RoadtwinError(f"{path}: not a readable label image ({exc})") from None
    bad = (a >= num_classes) & (a != IGNORE_INDEX)
    if bad.any():
        raise RoadtwinError(f"{path}: label value {int(a[bad].flat[0])} outside the classes 0..{num_classes - 1} "
                            f"({IGNORE_INDEX} = ignore)")
    if shape is not None and a.shape != tuple(shape):
        raise RoadtwinError(f"{path}: label is {a.shape[1]}x{a.shape[0]}, its image {shape[1]}x{shape[0]}")
    return a.astype(np.uint8)


def read_sample(sample: Sample, num_classes: int, size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Image and checked label of one pair; ``size`` (width, height) resizes both (image
    bilinear, label nearest), for synthetic frames rendered at another size."""
    img = read_image(sample.image)
    lab = read_label(sample.label, num_classes, img.shape[:2])
    if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
        img = np.asarray(Image.fromarray(img).resize(tuple(size), Image.BILINEAR))
        lab = np.asarray(Image.fromarray(lab).resize(tuple(size), Image.NEAREST))
    return img, lab


def load_folder(folder: str | Path, num_classes: int, size: tuple[int, int] | None = None,
                limit: int | None = None, workers: int = 8) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Every pair of a folder in memory: images (N, H, W, 3) uint8, labels (N, H, W) uint8, stems.
    All frames must share one size unless ``size`` is given."""
    samples = find_pairs(folder)[:limit]
    with ThreadPoolExecutor(max(1, workers)) as pool:
        pairs = list(pool.map(lambda s: read_sample(s, num_classes, size), samples))
    shapes = {p[0].shape for p in pairs}
    if len(shapes) > 1:
        first = samples[0]
        odd = next(s for s, p in zip(samples, pairs) if p[0].shape != pairs[0][0].shape)
        raise RoadtwinError(f"{folder}: frames of different sizes ({first.image.name} and {odd.image.name}); "
                            f"pass a size to resize them")
    return (np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs]), [s.stem for s in samples])


def _make_class():
    import torch
    from torch.utils.data import Dataset

    class SegmentationFolder(Dataset):
        """Items ``{"image": (3,H,W) float32 in [0,1], "label": (H,W) int64 (255 ignore), "stem"}``;
        ``transform`` is applied to the item dict. Pairs are found (and unpaired files refused)
        when the dataset is made; each label is range-checked when it is read."""

        def __init__(self, folder, num_classes: int, transform=None, size=None):
            self.folder = Path(folder)
            self.samples = find_pairs(self.folder)
            self.num_classes = int(num_classes)
            self.transform = transform
            self.size = size

        def __len__(self):
            return len(self.samples)

        def __getitem__(self, i):
            s = self.samples[i]
            img, lab = read_sample(s, self.num_classes, self.size)
            item = {"image": torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float() / 255.0,
                    "label": torch.from_numpy(lab.astype(np.int64)), "stem": s.stem}
            return self.transform(item) if self.transform else item

    return SegmentationFolder


__getattr__ = lazy_classes(__name__, {"SegmentationFolder": _make_class})
