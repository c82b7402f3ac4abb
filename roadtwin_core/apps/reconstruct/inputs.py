"""The ``inputs`` a reconstructor's ``run(inputs, params)`` receives, typed and checked.

The Reconstructor contract passes a dict (:meth:`SurfaceInputs.as_dict`, :meth:`DefectInputs.as_dict`
give the one ``roadtwin reconstruct`` passes); these dataclasses say which keys there are and
what each holds, and the checks fail on a missing file or an inconsistent set of inputs before a
plugin runs (one :class:`~roadtwin_core.RoadtwinError` naming the option).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from ...errors import RoadtwinError

__all__ = ["MASK_SUFFIXES", "ROAD_LABELS", "DefectInputs", "SurfaceInputs", "check_defect_inputs",
           "check_surface_inputs"]

ROAD_LABELS = (40, 44)   # SemanticKITTI road, parking: what a labelled frame keeps as road by default
MASK_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")   # images a --masks folder contributes


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

    def as_dict(self) -> dict[str, Any]:
        out = {"disparity": self.disparity, "left": self.left, "right": self.right, "K": self.K,
               "baseline": self.baseline, "transformed": self.transformed}
        if self.source is not None:
            out["source"] = self.source
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
    """A disparity map or a pair (not both), every file there."""
    if inputs.disparity is not None and (inputs.left is not None or inputs.right is not None):
        raise RoadtwinError("give --disparity or --left/--right, not both")
    _require(_files(inputs.disparity, inputs.left, inputs.right))
    return inputs
