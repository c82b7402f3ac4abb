"""Event camera output: ``events/events.h5`` with x, y (uint16), t (int64 microseconds), p (int8 +-1)
and the drive's frame times and poses (h5py)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ....errors import RoadtwinError

__all__ = ["write_events"]


def write_events(root: Path, events: dict[str, np.ndarray], times: np.ndarray, poses: Sequence[np.ndarray],
                 size: tuple[int, int], params: dict) -> dict:
    """Write ``events/events.h5``; returns its meta.json entry."""
    try:
        import h5py
    except ImportError:
        raise RoadtwinError("writing events needs h5py (pip install h5py)") from None
    (root / "events").mkdir(exist_ok=True)
    t_us = np.rint(np.asarray(events["t"], dtype=np.float64) * 1e6).astype(np.int64)
    with h5py.File(root / "events/events.h5", "w") as f:
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
    return {"file": "events/events.h5", "count": int(len(t_us)), "width": size[0],
            "height": size[1], "frames": int(len(times)), "duration_s": float(times[-1] - times[0]),
            "t_unit": "us", **params}

