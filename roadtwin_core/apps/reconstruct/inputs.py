"""The ``inputs`` a reconstructor's ``run(inputs, params)`` receives, typed and checked.

The Reconstructor contract passes a dict (:meth:`SurfaceInputs.as_dict`, :meth:`DefectInputs.as_dict`,
:meth:`PhotoSet.as_dict` give the one ``roadtwin reconstruct`` passes); these dataclasses say
which keys there are and what each holds, and the checks fail on a missing file or an
inconsistent set of inputs before a plugin runs (one :class:`~roadtwin_core.RoadtwinError` naming
the option).

Photos (``roadtwin reconstruct photos``) come in two steps: :class:`PhotoInputs` is what a user
names (photos or folders, the label folder, a class map, a rig preset and overrides);
:func:`check_photo_inputs` resolves it into the :class:`PhotoSet` a plugin reads (the photo files,
the class map's defect classes, the rig's numbers), which only the core can do.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Mapping, Sequence

import numpy as np
from PIL import Image, UnidentifiedImageError

from ...errors import RoadtwinError
from ...render.cameras import RIG_PRESETS
from ...render.classmap import ClassMap, load_class_map

__all__ = ["IMAGE_SUFFIXES", "MASK_SUFFIXES", "RIG_OVERRIDES", "ROAD_LABELS", "DefectInputs", "PhotoInputs",
           "PhotoSet", "SurfaceInputs", "check_defect_inputs", "check_photo_inputs", "check_surface_inputs",
           "defect_classes", "photo_rig", "road_classes"]

ROAD_LABELS = (40, 44)   # SemanticKITTI road, parking: what a labelled frame keeps as road by default
MASK_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")   # images a --masks folder contributes
IMAGE_SUFFIXES = MASK_SUFFIXES                                        # photos a folder contributes
#: ``--rig PRESET:key=value,...`` keys -> the rig's fields
RIG_OVERRIDES = {"height": "height_m", "pitch": "pitch_deg", "roll": "roll_deg", "hfov": "hfov_deg",
                 "width": "width", "height_px": "height"}


@dataclass
class SurfaceInputs:
    """What a ``produces="surface"`` reconstructor reads: LiDAR frames and where they were taken."""

    frames: Sequence[Any]                       # point cloud files (.ply, .pcd, .npz, .npy) or (N, 3) arrays
    poses: Any = None                           # KITTI / TUM pose file or (F, 4, 4); one frame without = world
    road_labels: Sequence[int] | None = ROAD_LABELS   # label values kept as road; None keeps every point
    masks: Sequence[Any] | None = None          # one road mask per frame (image files or arrays; a folder
                                                # stands for its images, sorted); needs K and cam_from_lidar
    K: Sequence[float] | None = None            # mask camera intrinsics fx, fy, cx, cy (pixels)
    cam_from_lidar: Any = None                  # 4x4 camera-from-LiDAR transform (text file or array)
    labels: Sequence[Any] | None = None         # per-frame label arrays, for array frames
    source: str | None = None                   # recorded on the asset (default: the first frame)

    def as_dict(self) -> dict[str, Any]:
        """The contract's dict: only the keys given (masks with their camera)."""
        out = {"frames": list(self.frames), "poses": self.poses,
               "road_labels": None if self.road_labels is None else list(self.road_labels)}
        if self.masks is not None:
            out.update(masks=list(self.masks), K=self.K, cam_from_lidar=self.cam_from_lidar)
        if self.labels is not None:
            out["labels"] = list(self.labels)
        if self.source is not None:
            out["source"] = self.source
        return out


@dataclass
class DefectInputs:
    """What a ``produces="defects"`` reconstructor reads: a disparity map or a rectified pair."""

    disparity: Any = None                       # disparity map (16-bit PNG, .npy, .pfm) or array
    left: Any = None                            # rectified left image (with right: SGBM disparity)
    right: Any = None
    K: Sequence[float] | None = None            # fx, fy, cx, cy or the 9 entries of K (pixels)
    baseline: float | None = None               # stereo baseline, m
    transformed: bool = False                   # the map is already transformed: defect pixels only
    source: str | None = None                   # recorded on every model (default: the input path)
    road_mask: Any = None                       # road mask image (file or array, nonzero = road), the
                                                # disparity's size: pixels off it are neither road nor defect

    def as_dict(self) -> dict[str, Any]:
        out = {"disparity": self.disparity, "left": self.left, "right": self.right, "K": self.K,
               "baseline": self.baseline, "transformed": self.transformed}
        if self.source is not None:
            out["source"] = self.source
        if self.road_mask is not None:
            out["road_mask"] = self.road_mask
        return out


def _files(*items: Any) -> list[Path]:
    """The paths among ``items`` (arrays are data, not files)."""
    return [Path(p) for p in items if isinstance(p, (str, Path))]


def _require(paths: list[Path]) -> None:
    for p in paths:
        if not p.exists():
            raise RoadtwinError(f"{p}: no such file")


def check_surface_inputs(inputs: SurfaceInputs) -> SurfaceInputs:
    """Every file there, masks one per frame with their camera; a copy with mask folders
    replaced by their images."""
    _require(_files(*inputs.frames, inputs.poses, *(inputs.masks or []), inputs.cam_from_lidar))
    if not inputs.masks:
        if inputs.K is not None or inputs.cam_from_lidar is not None:
            raise RoadtwinError("--K and --cam-from-lidar are only used with --masks")
        return dataclasses.replace(inputs, masks=None)
    masks = _mask_files(inputs.masks)
    if len(masks) != len(inputs.frames):
        raise RoadtwinError(f"--masks: {len(masks)} masks for {len(inputs.frames)} frames (one mask per frame)")
    if inputs.K is None:
        raise RoadtwinError("--masks needs the camera intrinsics --K fx,fy,cx,cy")
    if inputs.cam_from_lidar is None:
        raise RoadtwinError("--masks needs the camera-from-LiDAR extrinsic --cam-from-lidar FILE (4x4)")
    return dataclasses.replace(inputs, masks=masks)


def _mask_files(masks: Sequence[Any]) -> list[Any]:
    """One mask per frame: a folder contributes its images, sorted."""
    out: list[Any] = []
    for m in masks:
        if isinstance(m, (str, Path)) and Path(m).is_dir():
            found = sorted(q for q in Path(m).iterdir() if q.is_file() and q.suffix.lower() in MASK_SUFFIXES)
            if not found:
                raise RoadtwinError(f"{m}: no mask images (.png) in the folder")
            out += found
        else:
            out.append(m)
    return out


def check_defect_inputs(inputs: DefectInputs) -> DefectInputs:
    """A disparity map or a pair (not both), every file there, a road mask the disparity's size."""
    if inputs.disparity is not None and (inputs.left is not None or inputs.right is not None):
        raise RoadtwinError("give --disparity or --left/--right, not both")
    _require(_files(inputs.disparity, inputs.left, inputs.right))
    if inputs.road_mask is not None:
        _check_road_mask(inputs.road_mask, inputs.disparity if inputs.disparity is not None else inputs.left)
    return inputs


def _check_road_mask(mask: Any, image: Any) -> None:
    """``--road-mask``: a readable image of the same width and height as the disparity (that of
    ``image``: the disparity map, or the left image a pair's disparity is computed on)."""
    if isinstance(mask, (str, Path)) and not Path(mask).is_file():
        raise RoadtwinError(f"{mask}: no such road mask (--road-mask)")
    size = _image_size(mask, "road mask (--road-mask)")
    try:
        want = _image_size(image, "disparity")
    except RoadtwinError:
        return   # an unreadable disparity or left image: the plugin's own check names it
    if size is not None and want is not None and size != want:
        raise RoadtwinError(f"{mask if isinstance(mask, (str, Path)) else 'road mask array'}: the road mask is "
                            f"{size[0]}x{size[1]} px, the disparity {want[0]}x{want[1]} px (--road-mask)")


def _image_size(image: Any, what: str) -> tuple[int, int] | None:
    """(width, height) of an array, a .npy, a .pfm or an image file (its header only); None when
    there is nothing to size (no input, or a file the plugin reads and checks itself)."""
    if image is None:
        return None
    if not isinstance(image, (str, Path)):
        shape = np.shape(image)
        return (int(shape[1]), int(shape[0])) if len(shape) >= 2 else None
    path = Path(image)
    try:
        if path.suffix.lower() == ".npy":
            shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
            return (int(shape[1]), int(shape[0])) if len(shape) >= 2 else None
        if path.suffix.lower() == ".pfm":
            with path.open("rb") as f:
                f.readline()
                width, height = f.readline().split()[:2]
            return int(width), int(height)
        with Image.open(path) as img:
            return img.size
    except (OSError, ValueError, EOFError, UnidentifiedImageError):
        raise RoadtwinError(f"{path}: cannot read the {what} image") from None


@dataclass
class PhotoInputs:
    """What a user names for ``roadtwin reconstruct photos``: labelled road photos and the camera
    that took them (:func:`check_photo_inputs` resolves it)."""

    images: Sequence[Any]                         # photo files, or folders (their images, sorted)
    labels: Any                                   # label folder: <image stem>.png, one class id per pixel
    classmap: str = "builtin:road_defects_br"     # the labels' classes: builtin:NAME, NAME or a TOML file
    rig: str = "survey"                           # camera rig preset (roadtwin_core.render.cameras.RIG_PRESETS)
    rig_overrides: Mapping[str, float] = field(default_factory=dict)   # RIG_OVERRIDES keys -> values
    license: str | None = None                    # recorded on every asset (default: a LICENSE file beside)


@dataclass
class PhotoSet:
    """What a ``produces="defects"`` reconstructor for photos (``photo_defects``) reads."""

    images: list[Path]                            # photo files
    labels: Path                                  # label folder
    classes: dict[int, tuple[str, str]]           # dataset class id -> (class name, roadtwin defect type)
    rig: dict[str, Any]                           # name, width, height (px), hfov_deg, height_m, pitch_deg, roll_deg
    license: str | None = None
    classmap_source: str = "class map"            # for messages
    lane_classes: dict[int, str] = field(default_factory=dict)   # class id -> name of the lane (road_classes)

    def as_dict(self) -> dict[str, Any]:
        return {"images": list(self.images), "labels": self.labels, "classes": dict(self.classes),
                "rig": dict(self.rig), "license": self.license, "classmap_source": self.classmap_source,
                "lane_classes": dict(self.lane_classes)}


def defect_classes(classmap: ClassMap, defect_types: Collection[str]) -> dict[int, tuple[str, str]]:
    """{dataset class id: (class name, defect type)} for every class the map fills from one of
    ``defect_types`` by a plain entry (an ``ego`` rule's labels are the lane, not a defect); the
    type named like the class names it (road_defects_br's crack is filled from crack and alligator:
    a photo's crack is a crack), else the first such type in the map's order."""
    out: dict[int, tuple[str, str]] = {}
    for label, cls in classmap.plain.items():
        if label in defect_types and cls in classmap.classes:
            cid = classmap.classes.index(cls)
            if cid not in out or label == cls:
                out[cid] = (cls, label)
    return dict(sorted(out.items()))


def road_classes(classmap: ClassMap) -> dict[int, str]:
    """{dataset class id: class name} of the classes a photo shows plain road in: the class the
    roadtwin label ``driving`` maps to inside the ego mask (an ``ego`` rule: for
    ``road_defects_br`` the ego lane) or else by its plain entry, unless that is the class of
    everything unnamed (``background`` holds sky and verge too)."""
    cls = classmap.ego.get("driving") or classmap.plain.get("driving")
    if cls is None or cls not in classmap.classes or (cls == classmap.unknown and "driving" not in classmap.ego):
        return {}
    return {classmap.classes.index(cls): cls}


def photo_rig(preset: str, overrides: Mapping[str, float] | None = None) -> dict[str, Any]:
    """A rig preset's numbers with ``overrides`` (:data:`RIG_OVERRIDES` keys) over them: the rig
    fields a photo reconstructor reads. Its name is the preset's, with the overrides spelled out."""
    p = RIG_PRESETS.get(preset)
    if p is None:
        raise RoadtwinError(f"--rig: no rig preset {preset!r} (presets: {', '.join(sorted(RIG_PRESETS))})")
    rig: dict[str, Any] = {"name": p.name, "width": p.width, "height": p.height, "hfov_deg": p.hfov_deg,
                           "height_m": p.height_m, "pitch_deg": p.pitch_deg, "roll_deg": 0.0}
    for key, value in (overrides or {}).items():
        if key not in RIG_OVERRIDES:
            raise RoadtwinError(f"--rig: unknown key {key!r} (keys: {', '.join(RIG_OVERRIDES)})")
        v = float(value)
        if not math.isfinite(v):
            raise RoadtwinError(f"--rig: {key} = {value!r} is not finite")
        name = RIG_OVERRIDES[key]
        if name in ("width", "height"):
            if v != int(v):
                raise RoadtwinError(f"--rig: {key} is a number of pixels, got {value!r}")
            v = int(v)
        rig[name] = v
    if overrides:
        rig["name"] = f"{preset}:" + ",".join(f"{k}={v:g}" for k, v in overrides.items())
    if not (rig["height_m"] > 0 and rig["width"] > 0 and rig["height"] > 0 and 1 <= rig["hfov_deg"] <= 179
            and -90 <= rig["pitch_deg"] <= 90 and -180 <= rig["roll_deg"] <= 180):
        raise RoadtwinError(f"--rig: {rig['name']} needs a height above the road > 0 m, a positive image size, "
                            "hfov in [1, 179] deg, pitch in [-90, 90] deg and roll in [-180, 180] deg")
    return rig


def _photo_files(images: Sequence[Any]) -> list[Path]:
    """The photos: files as given, folders by their images, sorted."""
    if not images:
        raise RoadtwinError("no photos given")
    out: list[Path] = []
    for p in map(Path, images):
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise RoadtwinError(f"{p}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
            out += found
        elif not p.is_file():
            raise RoadtwinError(f"{p}: no such image")
        else:
            out.append(p)
    return out


def check_photo_inputs(inputs: PhotoInputs, defect_types: Collection[str]) -> PhotoSet:
    """Photos there, the label folder there, a class map with at least one class filled from one
    of ``defect_types`` (the registered types that are defects), a known rig -> the plugin's inputs."""
    images = _photo_files(inputs.images)
    labels = Path(inputs.labels)
    if not labels.is_dir():
        raise RoadtwinError(f"{labels}: label folder not found")
    cmap = load_class_map(inputs.classmap.removeprefix("builtin:"))
    classes = defect_classes(cmap, defect_types)
    if not classes:
        raise RoadtwinError(f"{cmap.source}: class map {cmap.name!r} has no defect class (none of its classes "
                            f"{', '.join(cmap.classes)} is filled from a defect type): nothing to reconstruct")
    return PhotoSet(images, labels, classes, photo_rig(inputs.rig, inputs.rig_overrides), inputs.license, cmap.source,
                    road_classes(cmap))
