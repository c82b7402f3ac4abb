"""KITTI-2015 stereo layout: ``kitti/training/image_2/000000_10.png``, ``image_3/`` (hard links to
the images), ``disp_occ_0/`` (uint16 disparity * 256, 0 = invalid), ``disp_noc_0/`` (same,
occluded pixels set to 0) and ``calib_cam_to_cam/000000.txt`` (P_rect_02 / P_rect_03, 3x4)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .images import link, save_png

__all__ = ["KittiWriter", "kitti_disparity_png"]

_DIRS = ("image_2", "image_3", "disp_occ_0", "disp_noc_0", "calib_cam_to_cam")


def kitti_disparity_png(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """KITTI-2015 encoding: uint16 = disparity * 256 (rounded), 0 = invalid; valid disparities
    too small to encode are stored as 1 (1/256 px), too large clipped at 65535."""
    d = np.rint(np.asarray(disparity, dtype=np.float64) * 256.0)
    d = np.clip(d, 1, 65535)
    return np.where(valid & (disparity > 0), d, 0).astype(np.uint16)



class KittiWriter:
    name = "kitti"
    needs_stereo = True

    def __init__(self, ds) -> None:
        self.ds = ds
        for d in _DIRS:
            (ds.root / "kitti/training" / d).mkdir(parents=True, exist_ok=True)

    def add(self, k: int, stem: str, frame, files: dict) -> dict:
        return self.commit(k, self.write(k, stem, frame, files))

    def commit(self, k: int, state) -> dict:
        return {}

    def write(self, k: int, stem: str, frame, files: dict) -> None:
        """This frame's files (thread-safe: touches nothing shared)."""
        root = self.ds.root
        kt = root / "kitti/training"
        name = f"{stem}_10.png"
        img_name = f"{stem}_10{Path(files['rgb']).suffix}"
        link(root / files["rgb"], kt / "image_2" / img_name)
        link(root / files["rgb_right"], kt / "image_3" / img_name)
        valid = frame.depth > 0
        save_png(kt / "disp_occ_0" / name, kitti_disparity_png(frame.disparity, valid))
        save_png(kt / "disp_noc_0" / name, kitti_disparity_png(frame.disparity, valid & ~frame.occluded))
        (kt / "calib_cam_to_cam" / f"{stem}.txt").write_text(self.calib())
        files.update(kitti_left=f"kitti/training/image_2/{img_name}", kitti_right=f"kitti/training/image_3/{img_name}",
                     disparity=f"kitti/training/disp_occ_0/{name}", disparity_noc=f"kitti/training/disp_noc_0/{name}")

    def calib(self) -> str:
        k = self.ds.intrinsics
        p2 = np.array([[k.fx, 0, k.cx, 0], [0, k.fy, k.cy, 0], [0, 0, 1, 0]])
        p3 = p2.copy()
        p3[0, 3] = -k.fx * float(self.ds.baseline)
        fmt = lambda m: " ".join(f"{x:.12e}" for x in m.ravel())  # noqa: E731
        return (f"S_rect_02: {k.width:.6e} {k.height:.6e}\nP_rect_02: {fmt(p2)}\n"
                f"S_rect_03: {k.width:.6e} {k.height:.6e}\nP_rect_03: {fmt(p3)}\n")

    def finish(self) -> None:
        pass
