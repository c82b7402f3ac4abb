"""Data of bench/perception.py: frames decoded once into uint8 arrays, fixed real subsets that
must hold potholes, the class-map check between real and synthetic folders, road-grouped folds
for the cross-validation of the mixed arm, and ``pack``.

Frames are decoded once (JPEG/PNG -> uint8 arrays) and, with a cache folder, kept as ``.npy``
files that the suite's parallel processes memory-map instead of decoding again; on the GPU they
live as uint8 tensors and are augmented there (bench/_perception_train.py), so no loader thread
can starve the GPU.
"""
from __future__ import annotations

import errno
import hashlib
import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roadtwin_core.datasets import find_pairs, load_folder, read_sample
from roadtwin_core.errors import RoadtwinError

CLASSES = ("background", "ego_lane", "crack", "pothole")
POTHOLE = CLASSES.index("pothole")
CLASS_FILES = ("classes.json", "mmseg/classes.json", "meta.json")


@dataclass
class Frames:
    images: np.ndarray       # (N, H, W, 3) uint8
    labels: np.ndarray       # (N, H, W) uint8, 255 ignore
    stems: list[str]
    folder: str

    def subset(self, idx) -> "Frames":
        idx = np.asarray(idx, dtype=np.int64)
        return Frames(self.images[idx], self.labels[idx], [self.stems[i] for i in idx], self.folder)

    def pothole_frames(self) -> np.ndarray:
        return np.flatnonzero((self.labels == POTHOLE).any((1, 2)))


def parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise RoadtwinError(f"--size: {text!r} is not WIDTHxHEIGHT") from None
    if w <= 0 or h <= 0:
        raise RoadtwinError(f"--size: {text!r} must be positive")
    return w, h


def load_frames(folder, size: tuple[int, int] | None, limit: int | None = None, cache: Path | None = None) -> Frames:
    """Decoded frames of a dataset folder; with ``cache``, decoded once and memory-mapped after."""
    folder = Path(folder)
    if cache is None:
        images, labels, stems = load_folder(folder, len(CLASSES), size=size, limit=limit)
        return Frames(images, labels, stems, str(folder))
    key = hashlib.sha1(f"{folder.resolve()}|{size}|{limit}".encode()).hexdigest()[:12]
    base = Path(cache) / f"frames_{key}"
    meta = base.with_suffix(".json")
    if not meta.exists():
        fr = load_frames(folder, size, limit)
        base.parent.mkdir(parents=True, exist_ok=True)
        _check_room(folder, base.parent, fr.images.nbytes + fr.labels.nbytes)
        for name, arr in (("images", fr.images), ("labels", fr.labels)):
            tmp = base.parent / f"{base.name}_{name}.tmp.npy"
            try:
                np.save(tmp, arr)
            except OSError as exc:
                tmp.unlink(missing_ok=True)
                if exc.errno != errno.ENOSPC:
                    raise
                _check_room(folder, base.parent, arr.nbytes, full=True)
            tmp.replace(base.parent / f"{base.name}_{name}.npy")
        tmp = meta.with_suffix(".tmp")
        tmp.write_text(json.dumps({"folder": str(folder), "stems": fr.stems}))
        tmp.replace(meta)
        return fr
    stems = json.loads(meta.read_text())["stems"]
    return Frames(np.load(base.parent / f"{base.name}_images.npy", mmap_mode="r"),
                  np.load(base.parent / f"{base.name}_labels.npy", mmap_mode="r"), stems, str(folder))


def _check_room(folder: Path, cache: Path, need: int, full: bool = False) -> None:
    """One line instead of numpy's OSError when the decoded copy of ``folder`` does not fit in
    ``cache``: separate ``train`` runs each decode their own (20,000 frames at 512x320 are ~13 GB),
    a ``suite`` decodes once for all its runs."""
    free = shutil.disk_usage(cache).free
    if full or need > free:
        raise RoadtwinError(f"{folder}: its decoded frames need {need / 1e9:.1f} GB in {cache}, "
                            f"{free / 1e9:.1f} GB free (runs of one table: `perception.py suite`, which decodes once)")


def subset_indices(n: int, fraction: float, seed: int) -> np.ndarray:
    """A fixed seeded subset of ``round(n * fraction)`` (at least 1) frame indices, sorted."""
    if not 0 < fraction <= 1:
        raise RoadtwinError(f"--fractions: {fraction} is not in (0, 1]")
    k = max(1, int(round(n * fraction)))
    return np.sort(np.random.default_rng(seed).choice(n, size=k, replace=False))


def real_subset(real: Frames, fraction: float, seed: int) -> Frames:
    """The fixed share of the real train frames; one without any pothole frame is an error (the
    copy-paste arm would have nothing to paste and pothole IoU nothing to learn)."""
    sub = real.subset(subset_indices(len(real.stems), fraction, seed))
    if len(sub.pothole_frames()) == 0:
        raise RoadtwinError(f"--fractions {fraction:g}: the {len(sub.stems)} real frame(s) drawn from {real.folder} "
                            f"(--subset-seed {seed}) hold no pothole pixel; use a larger fraction or another subset seed")
    return sub


# --------------------------------------------------------------------------------- class maps
def declared_classes(folder) -> tuple[list[str] | None, Path | None]:
    """The class names a dataset folder declares (classes.json, mmseg/classes.json or a render's
    meta.json, in the folder or its parent), or None where it declares none."""
    folder = Path(folder)
    for base in (folder, folder.parent):
        for name in CLASS_FILES:
            p = base / name
            if p.is_file():
                try:
                    raw = json.loads(p.read_text()).get("classes")
                except (ValueError, AttributeError):
                    raise RoadtwinError(f"{p}: not a JSON object with 'classes'") from None
                if raw is None:
                    continue
                return [c["name"] if isinstance(c, dict) else str(c) for c in raw], p
    return None, None


def check_class_maps(real_dir, synth_dir) -> None:
    """Real and synthetic labels must mean the same classes: each folder's declared classes (the
    bench's road_defects_br classes where a folder declares none) must be CLASSES, in order."""
    real, real_src = declared_classes(real_dir)
    synth, synth_src = declared_classes(synth_dir)
    real = real or list(CLASSES)
    if real != list(CLASSES):
        raise RoadtwinError(f"{real_src}: classes {real} are not the benchmark's {list(CLASSES)}")
    if synth is not None and synth != real:
        raise RoadtwinError(f"{synth_src}: synthetic classes {synth} differ from the real ones {real} "
                            f"({real_src or real_dir}); render with --classmap builtin:road_defects_br")


# ------------------------------------------------------------------------------------ folds
SOURCES_FILE = "sources.json"   # a synthetic set's provenance: bench/_synthetic_sources.py writes, the CV reads


def frame_stem(name) -> str:
    """A frame's stem from its name or path: folder and image extension dropped
    (``/train/images/1050564_DF_..._00368.jpg`` -> ``1050564_DF_..._00368``); a bare stem stays."""
    return re.sub(r"\.(jpe?g|png)$", "", Path(str(name)).name, flags=re.IGNORECASE)


def road_of(stem: str) -> str:
    """The road of a road_defects_br frame name ``<id>_<state>_<road>_...`` (e.g. RS_290)."""
    parts = Path(stem).name.split("_")
    return "_".join(parts[1:3]) if len(parts) >= 3 else stem


def cv_folds(stems: list[str], k: int, seed: int = 0) -> tuple[list[np.ndarray], str]:
    """k folds of frame indices for cross-validation inside the train frames: by road where there
    are at least k roads (roads dealt largest first to the smallest fold), else by frame (seeded)."""
    roads = [road_of(s) for s in stems]
    names, counts = np.unique(roads, return_counts=True)
    if len(names) >= k:
        folds: list[list[int]] = [[] for _ in range(k)]
        load = [0] * k
        for j in np.argsort(-counts, kind="stable"):
            f = int(np.argmin(load))
            folds[f] += [i for i, r in enumerate(roads) if r == names[j]]
            load[f] += int(counts[j])
        return [np.array(sorted(f)) for f in folds], "road"
    if len(stems) < 2:
        raise RoadtwinError(f"--cv-folds {k}: only {len(stems)} real frame(s) to split; give --mix RATIO:SCHEDULE")
    perm = np.random.default_rng(seed).permutation(len(stems))
    return [np.sort(p) for p in np.array_split(perm, min(k, len(stems)))], "frame"


# ------------------------------------------------------------------------------------- pack
def pack(src, dst, size, quality: int = 90, limit: int | None = None, log=print) -> None:
    """Copy a dataset folder as images/*.jpg + labels/*.png at one size, labels checked; its
    declared classes travel as classes.json."""
    from PIL import Image

    dst = Path(dst)
    samples = find_pairs(src)[:limit]
    (dst / "images").mkdir(parents=True, exist_ok=True)
    (dst / "labels").mkdir(parents=True, exist_ok=True)
    total = 0
    for s in samples:
        img, lab = read_sample(s, len(CLASSES), size)
        name = s.stem.replace("/", "_")
        Image.fromarray(img).save(dst / "images" / f"{name}.jpg", quality=quality)
        Image.fromarray(lab).save(dst / "labels" / f"{name}.png", optimize=True)
        total += (dst / "images" / f"{name}.jpg").stat().st_size + (dst / "labels" / f"{name}.png").stat().st_size
    classes, _ = declared_classes(src)
    if classes is None and (Path(src) / "mmseg").is_dir():
        classes, _ = declared_classes(Path(src) / "mmseg")
    if classes is not None:
        (dst / "classes.json").write_text(json.dumps({"classes": classes}))
    log(f"packed {len(samples)} frames into {dst} ({total / 2 ** 20:.1f} MiB)")
