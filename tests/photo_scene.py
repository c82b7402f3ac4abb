"""A labelled road photo made through a known rig, for the photo reconstructor's tests
(tests/plugins/test_photo_defects.py, tests/cli/test_reconstruct_photos.py): a textured
elliptical defect on a flat road, rendered by exact ray-plane projection per pixel (3x3
supersampled), with its label (3 pothole inside the ellipse, 1 road elsewhere)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from roadtwin_photo import PhotoRig

SURVEY = PhotoRig("survey", 512, 320, 60.0, 2.33, -25.1)   # roadtwin_core.render.cameras.RIG_PRESETS["survey"]
CLASSES = {2: ("crack", "crack"), 3: ("pothole", "pothole")}  # road_defects_br's defect classes
W, H = 1024, 640                                              # the train frames' full size


def ground_texture(xy: np.ndarray) -> np.ndarray:
    """A smooth asphalt-like grey pattern on the road (features ~8-30 cm), RGB 0..255."""
    x, y = xy[..., 0], xy[..., 1]
    g = (0.5 + 0.18 * np.sin(2 * np.pi * x / 0.31 + 0.4) * np.cos(2 * np.pi * y / 0.23)
         + 0.12 * np.sin(2 * np.pi * (x + 0.7 * y) / 0.13) + 0.08 * np.cos(2 * np.pi * (0.4 * x - y) / 0.47))
    return np.stack([g * 200, g * 190, g * 175], axis=-1)


def render_photo(rig: PhotoRig = SURVEY, centre=(6.0, 0.3), axes=(0.45, 0.3), ss: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The road seen through ``rig`` at W x H: the ground texture inside an ellipse (the defect,
    label 3), a flat grey road elsewhere (label 1). Each pixel averages ss x ss sub-rays."""
    off = (np.arange(ss) + 0.5) / ss - 0.5
    acc = np.zeros((H, W, 3))
    cover = np.zeros((H, W))
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    for du in off:
        for dv in off:
            xy, ok = rig.backproject((uu + du).ravel(), (vv + dv).ravel(), W, H)
            xy = xy.reshape(H, W, 2)
            q = ((xy[..., 0] - centre[0]) / axes[0]) ** 2 + ((xy[..., 1] - centre[1]) / axes[1]) ** 2
            inside = ok.reshape(H, W) & (q <= 1)
            acc += np.where(inside[..., None], ground_texture(np.nan_to_num(xy)), 110.0)
            cover += inside
    image = np.clip(acc / ss ** 2, 0, 255).astype(np.uint8)
    label = np.where(cover / ss ** 2 >= 0.5, 3, 1).astype(np.uint8)
    return image, label


def save_pair(folder: Path, stem: str, image: np.ndarray, label: np.ndarray) -> Path:
    """``folder/images/STEM.png`` and ``folder/labels/STEM.png``; returns the image's path."""
    (folder / "images").mkdir(parents=True, exist_ok=True)
    (folder / "labels").mkdir(parents=True, exist_ok=True)
    img = folder / "images" / f"{stem}.png"
    cv2.imwrite(str(img), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "labels" / f"{stem}.png"), label)
    return img
