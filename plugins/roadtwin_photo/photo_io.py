"""Reading labelled frames: the photo, its label, the pairs of a folder, the rig, the license.

The same checks as ``photo_defects`` makes (an image without its label, an unreadable file, a
label that is not one class id per pixel: one :class:`~roadtwin_core.RoadtwinError` each, before
any pixel is used), for the readers that came after it (``photo_surfaces``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from roadtwin_core import RoadtwinError

from .rectify import PhotoRig


def license_for(image: Path) -> str:
    """The first line of a LICENSE file beside the frame or up to three folders above it."""
    for d in [image.parent, *list(image.parents)[1:4]]:
        for name in ("LICENSE", "LICENSE.txt", "LICENSE.md", "COPYING"):
            f = d / name
            if f.is_file():
                try:
                    first = next((ln.strip() for ln in f.read_text(errors="replace").splitlines() if ln.strip()), "")
                except OSError:
                    continue
                return f"{first or 'license'} ({f})"
    return "unknown (no LICENSE file beside the frame)"


def read_rgb(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RoadtwinError(f"{path}: cannot read the image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_label(path: Path) -> np.ndarray:
    import cv2

    lab = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if lab is None:
        raise RoadtwinError(f"{path}: cannot read the label")
    if lab.ndim != 2:
        raise RoadtwinError(f"{path}: a label holds one class id per pixel (a single-channel PNG), got {lab.shape[2]} "
                            "channels")
    return lab


def rig_from(value: Any) -> PhotoRig:
    if isinstance(value, PhotoRig):
        return value
    if isinstance(value, dict):
        try:
            return PhotoRig(**value)
        except TypeError as exc:
            raise RoadtwinError(f"rig: {exc}") from None
    raise RoadtwinError(f"rig: expected a PhotoRig or its fields, got {type(value).__name__}")


def frame_pairs(inputs: dict[str, Any]) -> list[tuple[Path, Path]]:
    """[(image, its label)] of ``inputs['images']`` and the folder ``inputs['labels']``; every
    image must have ``<stem>.png`` there."""
    images = [Path(x) for x in inputs.get("images") or []]
    if not images:
        raise RoadtwinError("no images given")
    labels_dir = Path(inputs["labels"]) if inputs.get("labels") is not None else None
    if labels_dir is None or not labels_dir.is_dir():
        raise RoadtwinError(f"{labels_dir}: label folder not found")
    pairs = []
    for img in images:
        if not img.is_file():
            raise RoadtwinError(f"{img}: no such image")
        lab = labels_dir / f"{img.stem}.png"
        if not lab.is_file():
            raise RoadtwinError(f"{img}: no label {lab} (each image needs its label, same stem, .png)")
        pairs.append((img, lab))
    return pairs
