"""Image files and colour views shared by the dataset writers: PNG writing (Pillow; 16-bit PNGs
as mode ``I;16``, so writing needs no OpenCV), hard links, label / instance / scalar / normal
colour maps and the contact sheet."""
from __future__ import annotations

import functools
import os
import shutil
from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image, ImageDraw

from ....render import IGNORE_INDEX

__all__ = ["colorize_instances", "colorize_labels", "colorize_normals", "colorize_scalar", "link", "palette",
           "save_png", "write_contact_sheet", "write_image"]


def palette(n: int, names: Sequence[str]) -> np.ndarray:
    fixed = {"background": (70, 130, 180), "driving": (128, 64, 128), "ego_lane": (128, 64, 128), "junction": (160, 120, 160),
             "sidewalk": (244, 35, 232), "shoulder": (152, 251, 152), "pothole": (220, 20, 60),
             "crack": (255, 200, 0), "depression": (0, 0, 230), "bump": (0, 220, 220), "rut": (255, 120, 0),
             "ravelling": (190, 60, 90), "manhole": (110, 110, 110), "lane_marking": (157, 234, 50), "patch": (170, 90, 255)}
    rng = np.random.default_rng(12345)
    pal = rng.integers(40, 255, size=(256, 3)).astype(np.uint8)
    for i, name in enumerate(names[:n]):
        if name in fixed:
            pal[i] = fixed[name]
    pal[IGNORE_INDEX] = (0, 0, 0)
    return pal


def colorize_labels(labels: np.ndarray, palette: np.ndarray) -> np.ndarray:
    return palette[np.clip(labels, 0, 255).astype(np.uint8)]


def colorize_instances(inst: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(7)
    pal = rng.integers(60, 255, size=(int(inst.max()) + 1, 3)).astype(np.uint8)
    pal[0] = (0, 0, 0)
    return pal[inst]


def colorize_scalar(values: np.ndarray, valid: np.ndarray, lo: float, hi: float, log: bool = True) -> np.ndarray:
    """Values -> turbo colours on a fixed (log) range; invalid pixels black."""
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (np.log(v) - np.log(lo)) / (np.log(hi) - np.log(lo)) if log else (v - lo) / (hi - lo)
    x = np.clip(np.nan_to_num(x), 0.0, 1.0)
    img = _turbo_lut()[(x * 255).astype(np.int64)]
    img[~valid] = 0
    return img


@functools.lru_cache(maxsize=1)
def _turbo_lut() -> np.ndarray:
    """matplotlib's turbo colour map as 256 8-bit colours (built once: it cost ~1 ms a frame)."""
    from matplotlib import colormaps

    lut = (colormaps["turbo"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)
    lut.flags.writeable = False
    return lut


def colorize_normals(normal: np.ndarray) -> np.ndarray:
    valid = np.any(normal != 0, axis=-1)
    img = np.clip(np.rint((normal * 0.5 + 0.5) * 255), 0, 255).astype(np.uint8)
    img[~valid] = 0
    return img


def save_png(path: Path, array: np.ndarray) -> None:
    Image.fromarray(np.ascontiguousarray(array)).save(path, compress_level=1)  # uint16 -> 16-bit PNG


def write_image(path: Path, rgb8: np.ndarray, data: bytes | None) -> None:
    if data is not None:
        path.write_bytes(data)
    else:
        save_png(path, rgb8)


def link(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)



def write_contact_sheet(path: Path, rows: list[dict[str, np.ndarray]], thumb_width: int = 256) -> None:
    """One row per frame, one column per modality, labelled on top."""
    cols = [c for c in ("rgb", "semantic", "instance", "depth", "normal", "disparity") if all(c in r for r in rows)]
    h0, w0 = rows[0]["rgb"].shape[:2]
    tw = min(thumb_width, w0)
    th = max(1, round(h0 * tw / w0))
    header = 16
    sheet = Image.new("RGB", (tw * len(cols), header + th * len(rows)), (20, 20, 20))
    draw = ImageDraw.Draw(sheet)
    for j, c in enumerate(cols):
        draw.text((j * tw + 4, 2), c, fill=(230, 230, 230))
        for i, r in enumerate(rows):
            img = Image.fromarray(r[c]).resize((tw, th), Image.NEAREST if c in ("semantic", "instance") else Image.BILINEAR)
            sheet.paste(img, (j * tw, header + i * th))
    sheet.save(path)
