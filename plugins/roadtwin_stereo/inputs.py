"""The stereo reconstructor's parameters, its result, and the reading of its inputs (images,
disparity maps, road masks, poses, intrinsics): one line naming the input for anything wrong.
Split from the package module (plugins/roadtwin_stereo/__init__.py), which runs the pipeline."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roadtwin_core import DefectModel, RoadtwinError, field

from .mesh import DefectInstance
from .segment import load_disparity
from .texture import TextureSource
from .transform import RoadDisparityModel


@dataclass
class StereoDefectsParams:
    k_grow: float = field(3.0, lo=0.5, doc="candidate pixels: deviation below the road > k_grow robust sigma")
    k_seed: float = field(10.0, lo=0.5, doc="a defect's peak depth exceeds k_seed road-noise sigmas (small-scale, after the local road model)")
    k_region: float = field(12.0, lo=0.0, hi=1000.0, doc="metric inputs (a raw disparity or a pair, with K and "
                            "baseline): a candidate region is also a defect when its mean depth exceeds this x the "
                            "noise of a mean over as many road pixels, measured on the frame (segment.py step 5c; 0 = "
                            "off). Why: a far pothole is a shallow dip over many pixels that the peak rule (k_seed) "
                            "misses; 12 chosen on bench/loop.py's tuning cases (bench/README.md, loop section). Not applied "
                            "to transformed (normalised) maps, where the physical floor cannot guard it")
    road_refit_k: float = field(7.0, lo=0.0, hi=1000.0, doc="metric inputs: the local road model is refitted "
                                "without the regions reaching this many noise units below the road and above it "
                                "(road_model.py step 5; 0 = off). Why: a pothole under the model's 10-unit mask "
                                "pulled the road down and came out a median 28 % shallower (bench/loop_missed.py); "
                                "7 chosen on bench/loop.py's tuning cases. Not applied to transformed (normalised) "
                                "maps, as k_region")
    min_area_frac: float = field(0.0, lo=0.0, hi=1.0, doc="optional floor on a defect's area (fraction of the image)")
    grid_m: float = field(0.01, lo=1e-4, hi=1.0, doc="grid sampling step of the defect mesh (m)")
    disparity_scale: float = field(1.0, lo=1e-9, doc="integer disparity PNGs are divided by this (KITTI: 256)")
    max_disparity: int = field(128, lo=16, hi=1024, doc="SGBM disparity range (px)")
    min_depth_m: float = field(0.0, lo=0.0, doc="after meshing: drop models whose mesh is shallower than this (m); "
                               "the detector's own floor is floor_depth_m")
    floor_depth_m: float = field(0.01, lo=0.0, hi=1.0, doc="physical floor of the detector (metric inputs: a raw "
                                 "disparity or a pair, with K and baseline): a region is a defect only if it reaches "
                                 "this far (m; 90th percentile of its pixels) below the local road model. Why: the "
                                 "other thresholds are in units of the map's own noise, so a clean map lowers them "
                                 "until benign road shape passes; metres do not move with the matcher. 1 cm: the "
                                 "issue's depth tolerance (shallower is not a measured depth), under half the "
                                 "shallowest pothole on bench/loop.py's tuning cases (docs/stereo_detector.md). "
                                 "Not applied to transformed (normalised, unitless) maps; 0 = off")
    floor_area_m2: float = field(0.0, lo=0.0, hi=100.0, doc="physical floor of the detector (metric inputs): a "
                                 "region is a defect only if it covers this much road (m^2); 0 = off, the default. Why "
                                 "metres: a pixel count is a different area at 3 m and at 10 m. Why off: on "
                                 "bench/loop.py's tuning cases 0.02 m^2 (half their smallest pothole) removed only 7 "
                                 "of 112 false regions, and an area scales with the square of the calibration's "
                                 "scale (a nominal rig's real pothole fell under it; docs/stereo_detector.md)")
    subpixel_sigma_u_px: float = field(0.0, lo=0.0, hi=50.0, doc="left/right pairs: Gaussian window along the rows "
                                       "(px) of the Lucas-Kanade sub-pixel refinement of SGBM's disparity (0 = off, "
                                       "the default: refined maps are accurate to ~0.06 px on the road, but their local "
                                       "0.2-0.5 px errors pass the detector as potholes, floor or not: "
                                       "docs/stereo_detector.md; bench/loop.py uses 6)")
    subpixel_sigma_v_px: float = field(2.0, lo=0.1, hi=50.0, doc="the same window across the rows (px; narrow: a road "
                                       "far ahead is foreshortened along v)")
    subpixel_reject_error: float = field(1.3, lo=0.0, hi=100.0, doc="sub-pixel refinement: a match whose predicted "
                                         "standard error exceeds this x the frame's median is invalid (0 = keep all). "
                                         "Why: where the views disagree the refinement lands 0.2-0.8 px off, in patches "
                                         "the detector takes for potholes (subpixel.py; chosen on bench/loop.py's "
                                         "tuning cases, docs/stereo_detector.md)")
    subpixel_reject_residual: float = field(2.0, lo=0.0, hi=100.0, doc="sub-pixel refinement: a match whose residual "
                                            "(grey levels a shift leaves unexplained) exceeds this x the frame's median "
                                            "is invalid (0 = keep all); why: as subpixel_reject_error")
    border_px: int = field(0, lo=0, hi=1000, doc="regions reaching within this many pixels of the map's edge are "
                           "dropped (0 = keep, the default): cut by the edge, a region has no road rim on that side "
                           "to check its depth against; a camera driving on sees it whole later. On bench/loop.py's "
                           "tuning town most false detections touch the crop's top row (docs/stereo_detector.md)")
    texture: bool = field(True, doc="textured assets: each defect wears the left image's pixels of its footprint "
                          "(inputs 'rgb', else a pair's 'left'; texture.py), fading into the road at its outline")
    texel_m: float = field(0.0, lo=0.0, hi=0.1, doc="texture patch resolution on the road (m per texel); 0: the "
                           "image's own, one pixel at the defect's range (1-50 mm)")
    road_albedo: float = field(0.12, lo=0.0, hi=1.0, doc="linear luminance the road around a defect is scaled to, "
                               "so the patch is an albedo like the town's asphalt; 0 keeps the image's exposure")


@dataclass
class StereoResult:
    models: list[DefectModel]
    labels: np.ndarray                 # instance labels per pixel (0 = road)
    transformed: np.ndarray            # transformed disparity
    road_model: RoadDisparityModel | None
    instances: list[DefectInstance]
    texture: TextureSource | None = None   # the frame's left image + K when the assets are textured


def read_image(x: Any, what: str) -> tuple[np.ndarray, str]:
    import cv2

    if isinstance(x, np.ndarray):
        return x, what
    p = Path(x)
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RoadtwinError(f"{p}: cannot read {what} image")
    return img, str(p)


MIN_SIDE_PX = 16  # smaller maps hold no road model to fit


def read_disparity(path: Path, scale: float, transformed: bool) -> np.ndarray:
    """A disparity map file, checked at the edge: a readable file of real numbers, 2-D and at
    least MIN_SIDE_PX a side. An untransformed map's values <= 0 are invalid pixels (as for
    arrays); a transformed map may hold any finite value."""
    if path.is_dir():
        raise RoadtwinError(f"{path}: is a directory, not a disparity map")
    if not path.is_file():
        raise RoadtwinError(f"{path}: no such disparity map")
    if path.suffix.lower() == ".npy":
        try:
            head = np.load(path, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise RoadtwinError(f"{path}: cannot read as a .npy array ({exc})") from None
        if head.dtype.kind not in "iuf":
            raise RoadtwinError(f"{path}: disparity must hold real numbers, got dtype {head.dtype}")
        del head
    try:
        disp = load_disparity(path, scale)
    except (ValueError, TypeError, OSError) as exc:
        raise RoadtwinError(f"{path}: cannot read the disparity map ({exc})") from None
    if min(disp.shape) < MIN_SIDE_PX:
        raise RoadtwinError(f"{path}: disparity map is {disp.shape[1]}x{disp.shape[0]} px, too small to model a road "
                            f"(at least {MIN_SIDE_PX} px a side)")
    if not transformed:
        disp[disp <= 0] = np.nan
    return disp


def apply_road_mask(disp: np.ndarray, mask_in: Any, source: str) -> np.ndarray:
    """Pixels off the road mask (0) become invalid: a verge or a kerb's foot lies below the road
    and is not a defect."""
    mask, name = read_image(mask_in, "road mask")
    mask = (mask.max(axis=-1) if mask.ndim == 3 else mask) > 0
    if mask.shape != disp.shape:
        raise RoadtwinError(f"{name if name != 'road mask' else source}: road mask is {mask.shape[1]}x{mask.shape[0]} "
                            f"px, the disparity {disp.shape[1]}x{disp.shape[0]} px")
    out = disp.copy()
    out[~mask] = np.nan
    return out


def pose_of(inputs: dict[str, Any], who: str) -> np.ndarray:
    pose = inputs.get("cam_to_world")
    if pose is None:
        raise RoadtwinError(f"{who}: fusing pairs needs each pair's pose (inputs 'cam_to_world')")
    pose = np.asarray(pose, np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise RoadtwinError(f"{who}: cam_to_world must be a finite 4x4 matrix, got shape {pose.shape}")
    return pose


