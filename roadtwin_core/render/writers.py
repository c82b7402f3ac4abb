"""Dataset writers: rendered frames -> files the tools of the field load directly.

One output directory (the CLI builds it in a temporary directory and renames it into place)::

    images/000000.png                 left RGB, 8-bit sRGB (every format points here)
    images_right/000000.png           right RGB (stereo)
    kitti/training/image_2/000000_10.png, image_3/      KITTI-2015 stereo layout (hard links)
    kitti/training/disp_occ_0/000000_10.png             uint16 disparity * 256, 0 = invalid
    kitti/training/disp_noc_0/000000_10.png             same, occluded pixels set to 0
    kitti/training/calib_cam_to_cam/000000.txt          P_rect_02 / P_rect_03 (3x4)
    mmseg/img_dir/train/000000.png, mmseg/ann_dir/train/000000.png   uint8 class ids, 255 ignore
                                      (images are .jpg when a sensor model wrote JPEG bytes)
    coco/annotations/instances_train.json               COCO instances, RLE masks, file_name
                                                        relative to the output directory
    instance/000000.png               uint16 instance ids (0 = none; ids in meta.json "instances")
    depth/000000.npy, .png            float32 z-depth in metres (0 = no hit); colour-mapped view
    normal/000000.npy, .png           float32 unit normals, camera frame (OpenCV axes); RGB view
    events/events.h5                  x, y (uint16), t (int64 microseconds), p (int8 +-1)
    meta.json                         intrinsics, poses, class map, instances, files per frame
    preview.png                       contact sheet

Images are written with Pillow (16-bit PNGs as mode ``I;16``), so writing needs no OpenCV.
COCO RLE is encoded here (pycocotools' compressed string format, column-major runs starting
with zeros), so writing needs no pycocotools either; ``rle_decode`` reads it back.
"""
from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import RoadtwinError
from .cameras import Intrinsics
from .frames import Frame
from .scene import IGNORE_INDEX

FORMATS = ("kitti", "mmseg", "coco", "depth", "normal")


def parse_formats(text: str | Sequence[str] | None, stereo: bool) -> list[str]:
    """Comma-separated format names -> list; unknown names and kitti without stereo are errors."""
    if text is None:
        names = [f for f in FORMATS if f != "kitti" or stereo]
    else:
        parts = text.split(",") if isinstance(text, str) else list(text)
        names = [p.strip().lower() for p in parts if p.strip()]
        if not names:
            raise RoadtwinError(f"no output format given (known: {', '.join(FORMATS)})")
    unknown = [n for n in names if n not in FORMATS]
    if unknown:
        raise RoadtwinError(f"unknown format {unknown[0]!r} (known: {', '.join(FORMATS)})")
    if "kitti" in names and not stereo:
        raise RoadtwinError("format kitti is a stereo layout: add --stereo")
    return list(dict.fromkeys(names))


# ------------------------------------------------------------------------------ conversions
def to_srgb8(rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear radiance -> 8-bit sRGB: exponential tone curve, then the sRGB transfer function."""
    x = 1.0 - np.exp(-np.maximum(np.asarray(rgb, dtype=np.float32), 0.0) * exposure)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.clip(np.rint(s * 255.0), 0, 255).astype(np.uint8)


def kitti_disparity_png(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """KITTI-2015 encoding: uint16 = disparity * 256 (rounded), 0 = invalid; valid disparities
    too small to encode are stored as 1 (1/256 px), too large clipped at 65535."""
    d = np.rint(np.asarray(disparity, dtype=np.float64) * 256.0)
    d = np.clip(d, 1, 65535)
    return np.where(valid & (disparity > 0), d, 0).astype(np.uint16)


def rle_encode(mask: np.ndarray) -> dict:
    """Binary (H, W) mask -> COCO compressed RLE ``{"size": [H, W], "counts": str}``."""
    m = np.asarray(mask, dtype=bool)
    h, w = m.shape
    flat = m.ravel(order="F").astype(np.int8)
    change = np.flatnonzero(np.diff(flat)) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    counts = np.diff(bounds).tolist()
    if flat.size and flat[0] == 1:
        counts = [0] + counts
    if flat.size == 0:
        counts = [0]
    return {"size": [int(h), int(w)], "counts": _counts_to_string(counts)}


def _counts_to_string(counts: list[int]) -> str:
    out = []
    for i, c in enumerate(counts):
        x = int(c)
        if i > 2:
            x -= int(counts[i - 2])
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = (x != -1) if (ch & 0x10) else (x != 0)
            if more:
                ch |= 0x20
            out.append(chr(ch + 48))
    return "".join(out)


def _string_to_counts(s: str) -> list[int]:
    counts: list[int] = []
    p = 0
    while p < len(s):
        x, k, more = 0, 0, True
        while more:
            c = ord(s[p]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and (c & 0x10):
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


def rle_decode(rle: dict) -> np.ndarray:
    """COCO RLE (compressed string or uncompressed list counts) -> uint8 (H, W) mask."""
    h, w = rle["size"]
    counts = rle["counts"]
    if isinstance(counts, (bytes, str)):
        counts = _string_to_counts(counts.decode() if isinstance(counts, bytes) else counts)
    counts = np.asarray(counts, dtype=np.int64)
    if counts.sum() != h * w:
        raise ValueError(f"RLE counts sum to {counts.sum()}, mask has {h * w} pixels")
    values = np.arange(len(counts)) % 2
    flat = np.repeat(values, counts).astype(np.uint8)
    return flat.reshape((w, h)).T.copy()


def _palette(n: int, names: Sequence[str]) -> np.ndarray:
    fixed = {"background": (70, 130, 180), "driving": (128, 64, 128), "ego_lane": (128, 64, 128), "junction": (160, 120, 160),
             "sidewalk": (244, 35, 232), "shoulder": (152, 251, 152), "pothole": (220, 20, 60),
             "crack": (255, 200, 0), "depression": (0, 0, 230), "bump": (0, 220, 220), "rut": (255, 120, 0),
             "manhole": (110, 110, 110), "lane_marking": (157, 234, 50), "patch": (170, 90, 255)}
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
    from matplotlib import colormaps

    v = np.asarray(values, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (np.log(v) - np.log(lo)) / (np.log(hi) - np.log(lo)) if log else (v - lo) / (hi - lo)
    x = np.clip(np.nan_to_num(x), 0.0, 1.0)
    lut = (colormaps["turbo"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)
    img = lut[(x * 255).astype(np.int64)]
    img[~valid] = 0
    return img


def colorize_normals(normal: np.ndarray) -> np.ndarray:
    valid = np.any(normal != 0, axis=-1)
    img = np.clip(np.rint((normal * 0.5 + 0.5) * 255), 0, 255).astype(np.uint8)
    img[~valid] = 0
    return img


def save_png(path: Path, array: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(array)).save(path, compress_level=1)  # uint16 -> 16-bit PNG


def _write_image(path: Path, rgb8: np.ndarray, data: bytes | None) -> None:
    if data is not None:
        path.write_bytes(data)
    else:
        save_png(path, rgb8)


def _link(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


# ---------------------------------------------------------------------------------- writer
@dataclass
class DatasetWriter:
    root: Path
    formats: list[str]
    intrinsics: Intrinsics
    classes: list[str]
    instances: list[dict]
    baseline: float | None = None
    min_instance_pixels: int = 4
    preview_frames: int = 6
    categories: list[str] = field(default_factory=list)   # COCO categories (defect types), ids 1..
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        self.frames_meta: list[dict] = []
        self.coco_images: list[dict] = []
        self.coco_annotations: list[dict] = []
        self.previews: list[dict[str, np.ndarray]] = []
        self.events_meta: dict | None = None
        self.palette = _palette(len(self.classes), self.classes)
        # every defect type is a COCO category, seen or not (stable ids across renders)
        self.categories = list(self.categories) or sorted({i["type"] for i in self.instances})
        dirs = ["images"]
        if self.baseline:
            dirs.append("images_right")
        if "kitti" in self.formats:
            dirs += [f"kitti/training/{d}" for d in ("image_2", "image_3", "disp_occ_0", "disp_noc_0",
                                                       "calib_cam_to_cam")]
        if "mmseg" in self.formats:
            dirs += ["mmseg/img_dir/train", "mmseg/ann_dir/train"]
        if "coco" in self.formats:
            dirs += ["coco/annotations", "instance"]
        for f in ("depth", "normal"):
            if f in self.formats:
                dirs.append(f)
        for d in dirs:
            (self.root / d).mkdir(parents=True, exist_ok=True)

    def add(self, frame: Frame, rgb8: np.ndarray | None = None, image_bytes: bytes | None = None,
            rgb8_right: np.ndarray | None = None, image_bytes_right: bytes | None = None,
            record: dict | None = None) -> None:
        """Write one frame. ``rgb8`` / ``image_bytes``: the image as the camera recorded it (8-bit
        sRGB, and its JPEG bytes when a sensor model encoded it: written as ``.jpg`` unchanged);
        default: ``frame.rgb`` tone-mapped, as PNG. ``record``: extra per-frame metadata."""
        k = len(self.frames_meta)
        stem = f"{k:06d}"
        files: dict[str, str] = {}
        root = self.root
        if (frame.rgb is None and rgb8 is None) or frame.depth is None or frame.semantic is None:
            raise RoadtwinError("renderer returned a frame without rgb, depth or semantic")
        rgb8 = to_srgb8(frame.rgb) if rgb8 is None else rgb8
        ext = ".jpg" if image_bytes is not None else ".png"
        _write_image(root / "images" / f"{stem}{ext}", rgb8, image_bytes)
        files["rgb"] = f"images/{stem}{ext}"
        semantic = frame.semantic.astype(np.uint8)
        if self.baseline:
            if (frame.rgb_right is None and rgb8_right is None) or frame.disparity is None or frame.occluded is None:
                raise RoadtwinError("renderer returned a stereo frame without right image or disparity")
            rgb8_right = to_srgb8(frame.rgb_right) if rgb8_right is None else rgb8_right
            ext_r = ".jpg" if image_bytes_right is not None else ".png"
            _write_image(root / "images_right" / f"{stem}{ext_r}", rgb8_right, image_bytes_right)
            files["rgb_right"] = f"images_right/{stem}{ext_r}"
        if "kitti" in self.formats:
            kt = root / "kitti/training"
            name = f"{stem}_10.png"
            img_name = f"{stem}_10{Path(files['rgb']).suffix}"
            _link(root / files["rgb"], kt / "image_2" / img_name)
            _link(root / files["rgb_right"], kt / "image_3" / img_name)
            valid = frame.depth > 0
            save_png(kt / "disp_occ_0" / name, kitti_disparity_png(frame.disparity, valid))
            save_png(kt / "disp_noc_0" / name, kitti_disparity_png(frame.disparity, valid & ~frame.occluded))
            (kt / "calib_cam_to_cam" / f"{stem}.txt").write_text(self._kitti_calib())
            files.update(kitti_left=f"kitti/training/image_2/{img_name}", kitti_right=f"kitti/training/image_3/{img_name}",
                         disparity=f"kitti/training/disp_occ_0/{name}", disparity_noc=f"kitti/training/disp_noc_0/{name}")
        if "mmseg" in self.formats:
            _link(root / files["rgb"], root / "mmseg/img_dir/train" / f"{stem}{ext}")
            save_png(root / "mmseg/ann_dir/train" / f"{stem}.png", semantic)
            files["semantic"] = f"mmseg/ann_dir/train/{stem}.png"
        visible = []
        if "coco" in self.formats:
            inst = frame.instance.astype(np.int64)
            save_png(root / "instance" / f"{stem}.png", inst.astype(np.uint16))
            files["instance"] = f"instance/{stem}.png"
            h, w = inst.shape
            self.coco_images.append({"id": k + 1, "file_name": files["rgb"], "width": w, "height": h})
            ids, counts = np.unique(inst[inst > 0], return_counts=True)
            for iid, n in zip(ids.tolist(), counts.tolist()):
                if n < self.min_instance_pixels:
                    continue
                meta = self.instances[iid - 1]
                mask = inst == iid
                ys, xs = np.nonzero(mask)
                self.coco_annotations.append({
                    "id": len(self.coco_annotations) + 1, "image_id": k + 1,
                    "category_id": self.categories.index(meta["type"]) + 1,
                    "segmentation": rle_encode(mask), "area": int(n),
                    "bbox": [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)],
                    "iscrowd": 0, "instance_id": iid, "defect_id": meta["defect_id"]})
                visible.append(iid)
        if "depth" in self.formats:
            np.save(root / "depth" / f"{stem}.npy", frame.depth.astype(np.float32))
            save_png(root / "depth" / f"{stem}.png", colorize_scalar(frame.depth, frame.depth > 0, 1.0, 200.0))
            files["depth"] = f"depth/{stem}.npy"
        if "normal" in self.formats:
            np.save(root / "normal" / f"{stem}.npy", frame.normal.astype(np.float32))
            save_png(root / "normal" / f"{stem}.png", colorize_normals(frame.normal))
            files["normal"] = f"normal/{stem}.npy"
        entry = {"index": k, "stem": stem, "cam_to_world": frame.camera.cam_to_world.tolist(), "files": files}
        if frame.time_s is not None:
            entry["time_s"] = frame.time_s
        if frame.right_camera is not None:
            entry["right_cam_to_world"] = frame.right_camera.cam_to_world.tolist()
        if "coco" in self.formats:
            entry["instances_visible"] = visible
        entry.update(record or {})
        self.frames_meta.append(entry)
        if len(self.previews) < self.preview_frames:
            self.previews.append(self._thumbs(frame, rgb8))

    def _kitti_calib(self) -> str:
        k = self.intrinsics
        p2 = np.array([[k.fx, 0, k.cx, 0], [0, k.fy, k.cy, 0], [0, 0, 1, 0]])
        p3 = p2.copy()
        p3[0, 3] = -k.fx * float(self.baseline)
        fmt = lambda m: " ".join(f"{x:.12e}" for x in m.ravel())  # noqa: E731
        return (f"S_rect_02: {k.width:.6e} {k.height:.6e}\nP_rect_02: {fmt(p2)}\n"
                f"S_rect_03: {k.width:.6e} {k.height:.6e}\nP_rect_03: {fmt(p3)}\n")

    def _thumbs(self, frame: Frame, rgb8: np.ndarray) -> dict[str, np.ndarray]:
        valid = frame.depth > 0
        t = {"rgb": rgb8, "semantic": colorize_labels(frame.semantic, self.palette),
             "depth": colorize_scalar(frame.depth, valid, 1.0, 200.0)}
        if frame.instance is not None:
            t["instance"] = colorize_instances(frame.instance.astype(np.int64))
        if frame.normal is not None:
            t["normal"] = colorize_normals(frame.normal)
        if frame.disparity is not None:
            d = frame.disparity
            t["disparity"] = colorize_scalar(d, valid & ~frame.occluded, 0.5, max(float(d.max()), 1.0))
        return t

    def write_events(self, events: dict[str, np.ndarray], times: np.ndarray, poses: Sequence[np.ndarray],
                     size: tuple[int, int], params: dict) -> None:
        try:
            import h5py
        except ImportError:
            raise RoadtwinError("writing events needs h5py (pip install h5py)") from None
        (self.root / "events").mkdir(exist_ok=True)
        t_us = np.rint(np.asarray(events["t"], dtype=np.float64) * 1e6).astype(np.int64)
        with h5py.File(self.root / "events/events.h5", "w") as f:
            f.create_dataset("x", data=events["x"].astype(np.uint16), compression="gzip")
            f.create_dataset("y", data=events["y"].astype(np.uint16), compression="gzip")
            f.create_dataset("t", data=t_us, compression="gzip")
            f.create_dataset("p", data=events["p"].astype(np.int8), compression="gzip")
            f.create_dataset("frame_t", data=np.rint(np.asarray(times) * 1e6).astype(np.int64))
            f.create_dataset("frame_cam_to_world", data=np.asarray(poses, dtype=np.float64))
            f.attrs["width"], f.attrs["height"] = size
            f.attrs["t_unit"] = "us"
            f.attrs["polarity"] = "+1 brighter, -1 darker"
            for key, v in params.items():
                f.attrs[key] = v
        self.events_meta = {"file": "events/events.h5", "count": int(len(t_us)), "width": size[0],
                            "height": size[1], "frames": int(len(times)), "duration_s": float(times[-1] - times[0]),
                            "t_unit": "us", **params}

    def finish(self, extra: dict | None = None) -> dict:
        root = self.root
        if "coco" in self.formats:
            coco = {"info": {"description": "roadtwin synthetic road defects", "version": "1.0"},
                    "licenses": [], "images": self.coco_images, "annotations": self.coco_annotations,
                    "categories": [{"id": i + 1, "name": n, "supercategory": "road_defect"}
                                   for i, n in enumerate(self.categories)]}
            (root / "coco/annotations/instances_train.json").write_text(json.dumps(coco))
        if "mmseg" in self.formats:
            (root / "mmseg/classes.json").write_text(json.dumps(
                {"classes": self.classes, "palette": self.palette[:len(self.classes)].tolist(),
                 "ignore_index": IGNORE_INDEX}, indent=1))
        meta = {
            "format": "roadtwin-render/1",
            "conventions": {
                "world": "Z up, metres (the town's frame)",
                "camera": "OpenCV: x right, y down, z forward; cam_to_world maps camera to world coordinates",
                "pixels": "u = fx X/Z + cx, v = fy Y/Z + cy, pixel centres at integer coordinates",
                "depth": "z-depth along the optical axis in metres, float32, 0 = no hit",
                "normal": "unit surface normal in camera coordinates facing the camera, float32, 0 = no hit",
                "disparity": "left view, f*B/Z pixels; KITTI PNG uint16 = disparity*256, 0 = invalid; "
                             "disp_noc_0 also 0 where the point is hidden from the right camera",
                "semantic": f"uint8 class ids (see classes), {IGNORE_INDEX} = ignore",
                "instance": "uint16 instance ids, 0 = none (see instances)",
                "rgb": "8-bit sRGB of linear radiance through 1 - exp(-x)",
            },
            "intrinsics": self.intrinsics.as_dict(),
            "stereo": {"baseline_m": self.baseline} if self.baseline else None,
            "formats": self.formats,
            "classes": [{"id": i, "name": n} for i, n in enumerate(self.classes)],
            "ignore_index": IGNORE_INDEX,
            "coco_categories": [{"id": i + 1, "name": n} for i, n in enumerate(self.categories)],
            "instances": self.instances,
            "frames": self.frames_meta,
            "events": self.events_meta,
            **self.info, **(extra or {}),
        }
        (root / "meta.json").write_text(json.dumps(meta, indent=1))
        if self.previews:
            write_contact_sheet(root / "preview.png", self.previews)
        return meta


def write_contact_sheet(path: Path, rows: list[dict[str, np.ndarray]], thumb_width: int = 256) -> None:
    """One row per frame, one column per modality, labelled on top."""
    from PIL import Image, ImageDraw

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
