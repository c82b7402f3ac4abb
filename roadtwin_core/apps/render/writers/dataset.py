"""The dataset writer: rendered frames -> files the tools of the field load directly.

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

This module writes what every render has (images, meta.json, the contact sheet, events) and hands
each frame to the writers of the chosen formats (``registry.WRITERS``, one module per format).
"""
from __future__ import annotations

import json
import os
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from ....errors import RoadtwinError
from ....render import IGNORE_INDEX, Frame, Intrinsics, to_srgb8
from .events import write_events
from .images import (colorize_instances, colorize_labels, colorize_normals, colorize_scalar, link, palette,
                     write_contact_sheet, write_image)
from .registry import WRITERS

__all__ = ["DatasetWriter", "EncodedFrame", "WrittenFrame", "meta_json"]


@dataclass
class WrittenFrame:
    """A frame whose files are written but not yet recorded (:meth:`DatasetWriter.commit`)."""

    index: int
    stem: str
    frame: Frame
    files: dict
    states: list                 # per writer that wrote at write time: what its commit records
    thumbs: dict | None          # the contact sheet's row (first frames only)

    def without_arrays(self) -> "WrittenFrame":
        """This frame without its arrays: what commit needs once every writer wrote at write time
        (from a worker process the arrays would travel back for nothing)."""
        f = self.frame
        return replace(self, frame=replace(f, rgb=None, depth=None, normal=None, semantic=None, instance=None,
                                           face=None, rgb_right=None, disparity=None, occluded=None))

    def kept(self, keep_frame: bool) -> "WrittenFrame":
        """This frame as it travels to the committing writer: with its arrays where writers that
        run at commit need them (``keep_frame``), else :meth:`without_arrays`."""
        return self if keep_frame else self.without_arrays()


@dataclass
class EncodedFrame:
    """A frame's files as bytes, encoded by another process (:meth:`DatasetWriter.encode`) and
    written as they are by :meth:`DatasetWriter.write_encoded`: the writing process then only
    writes bytes and commits (``gpu_shards``: the GPU tasks' worker processes encode)."""

    written: WrittenFrame        # arrays dropped when every writer wrote at write time
    files: dict[str, bytes]      # path relative to the dataset root -> the file's bytes
    links: dict[str, str]        # hard link (relative path) -> the file it links to
    placed: bool = False         # the files are already in the dataset's root (:meth:`DatasetWriter.place`)


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
    available: dict | None = None        # registry.available_formats(...) (default: the core's formats)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        self.frames_meta: list[dict] = []
        self.previews: list[dict[str, np.ndarray]] = []
        self._sheet: Future | None = None     # preview.png being drawn, once its rows are in
        self.events_meta: dict | None = None
        self.palette = palette(len(self.classes), self.classes)
        # every defect type is a COCO category, seen or not (stable ids across renders)
        self.categories = list(self.categories) or sorted({i["type"] for i in self.instances})
        (self.root / "images").mkdir(parents=True, exist_ok=True)
        if self.baseline:
            (self.root / "images_right").mkdir(parents=True, exist_ok=True)
        self.writers = [writer(self) for name, writer in (self.available or WRITERS).items() if name in self.formats]

    def _write_view(self, folder: str, stem: str, rgb8: np.ndarray, image_bytes: bytes | None) -> str:
        """One camera's image: the JPEG bytes a sensor model encoded, else ``rgb8`` as PNG; returns
        its path relative to the dataset root."""
        rel = f"{folder}/{stem}{'.jpg' if image_bytes is not None else '.png'}"
        write_image(self.root / rel, rgb8, image_bytes)
        return rel

    def add(self, frame: Frame, rgb8: np.ndarray | None = None, image_bytes: bytes | None = None,
            rgb8_right: np.ndarray | None = None, image_bytes_right: bytes | None = None,
            record: dict | None = None) -> None:
        """Write one frame. ``rgb8`` / ``image_bytes``: the image as the camera recorded it (8-bit
        sRGB, and its JPEG bytes when a sensor model encoded it: written as ``.jpg`` unchanged);
        default: ``frame.rgb`` tone-mapped, as PNG. ``record``: extra per-frame metadata."""
        self.commit(self.write(len(self.frames_meta), frame, rgb8, image_bytes, rgb8_right, image_bytes_right), record)

    def write(self, k: int, frame: Frame, rgb8: np.ndarray | None = None, image_bytes: bytes | None = None,
              rgb8_right: np.ndarray | None = None, image_bytes_right: bytes | None = None) -> "WrittenFrame":
        """Frame ``k``'s files (as :meth:`add`), without recording it: frames may be written on
        several threads at once, then :meth:`commit`-ed in frame order. Formats whose writer has
        no ``write`` (plugins' writers) are written at commit."""
        stem = f"{k:06d}"
        files: dict[str, str] = {}
        if (frame.rgb is None and rgb8 is None) or frame.depth is None or frame.semantic is None:
            raise RoadtwinError("renderer returned a frame without rgb, depth or semantic")
        rgb8 = to_srgb8(frame.rgb) if rgb8 is None else rgb8
        files["rgb"] = self._write_view("images", stem, rgb8, image_bytes)
        if self.baseline:
            if (frame.rgb_right is None and rgb8_right is None) or frame.disparity is None or frame.occluded is None:
                raise RoadtwinError("renderer returned a stereo frame without right image or disparity")
            rgb8_right = to_srgb8(frame.rgb_right) if rgb8_right is None else rgb8_right
            files["rgb_right"] = self._write_view("images_right", stem, rgb8_right, image_bytes_right)
        states = [w.write(k, stem, frame, files) for w in self._parallel_writers()]
        thumbs = self._thumbs(frame, rgb8) if k < self.preview_frames else None
        return WrittenFrame(k, stem, frame, files, states, thumbs)

    def spec(self) -> dict:
        """What makes a writer of this dataset elsewhere (``DatasetWriter(root=scratch, **spec)``):
        every field but the root and the plugins' formats (their writers run at commit here)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("root", "available")}

    def encode(self, k: int, frame: Frame, rgb8: np.ndarray | None = None, image_bytes: bytes | None = None,
               rgb8_right: np.ndarray | None = None, image_bytes_right: bytes | None = None,
               keep_frame: bool = False) -> EncodedFrame:
        """Frame ``k``'s files as bytes: :meth:`write` into this writer's root (a scratch folder of
        one process, holding nothing else), read back and removed, so the bytes are those
        :meth:`write` makes. ``keep_frame``: keep the arrays (writers that run at commit need them)."""
        written = self.write(k, frame, rgb8, image_bytes, rgb8_right, image_bytes_right)
        files: dict[str, bytes] = {}
        links: dict[str, str] = {}
        first: dict[tuple, str] = {}
        for folder, _, names in sorted(os.walk(self.root)):
            for name in sorted(names):
                path = Path(folder) / name
                rel = path.relative_to(self.root).as_posix()
                st = path.stat()
                if (st.st_dev, st.st_ino) in first:
                    links[rel] = first[(st.st_dev, st.st_ino)]
                else:
                    first[(st.st_dev, st.st_ino)] = rel
                    files[rel] = path.read_bytes()
                path.unlink()
        return EncodedFrame(written.kept(keep_frame), files, links)

    def place(self, k: int, frame: Frame, rgb8: np.ndarray | None = None, image_bytes: bytes | None = None,
              rgb8_right: np.ndarray | None = None, image_bytes_right: bytes | None = None,
              keep_frame: bool = False) -> EncodedFrame:
        """Frame ``k``'s files written by :meth:`write` straight into this writer's root, the
        staging folder of the writer that commits them (another process's, on the same
        filesystem): an :class:`EncodedFrame` without bytes, ``placed``, which that writer's
        :meth:`write_encoded` only hands to commit. ``keep_frame`` as in :meth:`encode`."""
        written = self.write(k, frame, rgb8, image_bytes, rgb8_right, image_bytes_right)
        return EncodedFrame(written.kept(keep_frame), {}, {}, placed=True)

    def write_encoded(self, encoded: EncodedFrame) -> WrittenFrame:
        """An :class:`EncodedFrame`'s files written as they are (hard links as links; nothing
        when they were ``placed`` already); returns what :meth:`commit` records."""
        for rel, data in encoded.files.items():
            (self.root / rel).write_bytes(data)
        for rel, target in encoded.links.items():
            link(self.root / target, self.root / rel)
        return encoded.written

    def _parallel_writers(self) -> list:
        """The writers whose files :meth:`write` makes: every one with a ``write``, up to the first without."""
        out = []
        for w in self.writers:
            if not hasattr(w, "write"):
                break
            out.append(w)
        return out

    def commit(self, written: "WrittenFrame", record: dict | None = None) -> None:
        """Record a frame :meth:`write` wrote (frames in order: ``written.index`` is the next one)."""
        k, stem, frame, files = written.index, written.stem, written.frame, written.files
        if k != len(self.frames_meta):
            raise RoadtwinError(f"dataset writer: frame {k} committed out of order (expected {len(self.frames_meta)})")
        extra: dict = {}
        for w, state in zip(self.writers, written.states):
            extra.update(w.commit(k, state))
        for w in self.writers[len(written.states):]:
            extra.update(w.add(k, stem, frame, files))
        entry = {"index": k, "stem": stem, "cam_to_world": frame.camera.cam_to_world.tolist(), "files": files}
        if frame.time_s is not None:
            entry["time_s"] = frame.time_s
        if frame.right_camera is not None:
            entry["right_cam_to_world"] = frame.right_camera.cam_to_world.tolist()
        entry.update(extra)
        entry.update(record or {})
        self.frames_meta.append(entry)
        if written.thumbs is not None and len(self.previews) < self.preview_frames:
            self.previews.append(written.thumbs)
            if len(self.previews) == self.preview_frames:      # drawn while the other frames render
                pool = ThreadPoolExecutor(1, thread_name_prefix="contact-sheet")
                self._sheet = pool.submit(write_contact_sheet, self.root / "preview.png", list(self.previews))
                pool.shutdown(wait=False)

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
        self.events_meta = write_events(self.root, events, times, poses, size, params)

    def finish(self, extra: dict | None = None) -> dict:
        root = self.root
        for w in self.writers:
            w.finish()
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
        (root / "meta.json").write_text(meta_json(meta))
        if self._sheet is not None:
            self._sheet.result()
        elif self.previews:
            write_contact_sheet(root / "preview.png", self.previews)
        return meta


def meta_json(meta: dict) -> str:
    """``meta`` as JSON indented by one space, but each frame's record on one line. Why: Python
    indents with its pure-Python encoder (~0.3 s for 3,000 frames on a fast core, a tenth of a
    GPU render); a frame a line goes through the C encoder and still reads and diffs by frame."""
    placeholder = "\0frames\0"
    head = json.dumps({**meta, "frames": placeholder}, indent=1)
    frames = meta.get("frames") or []
    body = "[\n" + ",\n".join("  " + json.dumps(f) for f in frames) + "\n ]" if frames else "[]"
    return head.replace(json.dumps(placeholder), body, 1)
