"""What bench/loop.py reads from a drive and from its town (issue 20, item 5): the bag's LiDAR
scans (de-skewed to the map with the drive's poses), its stereo pairs with their calibration and
ground-truth instances, and the twin's own truth (road heights by vertical rays on the collision
mesh, defect footprints and depths).

Only the bag's standard messages and the drive's ``frames.json``/``summary.json`` are read: the
loop uses what a user of the drive gets.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

EPOCH_S = 1_700_000_000          # the bag's stamps are the drive's clock + this (apps/drive/bag.py)
PAVED = ("driving", "junction", "shoulder", "lane_marking", "bump", "crack", "depression", "manhole", "patch",
         "pothole", "rut")        # LiDAR classes kept as road surface


def _stamp(header) -> float:
    return (header.stamp.sec - EPOCH_S) + header.stamp.nanosec * 1e-9


def _matrix(tr) -> np.ndarray:
    T = np.eye(4)
    q = tr.rotation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [tr.translation.x, tr.translation.y, tr.translation.z]
    return T


class Bag:
    """Reads one drive's ``bag/`` (rosbags, ROS 2 Humble types)."""

    def __init__(self, drive_dir: Path) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.dir = Path(drive_dir)
        self.ts = get_typestore(Stores.ROS2_HUMBLE)

    def messages(self, topic: str):
        from rosbags.rosbag2 import Reader

        with Reader(self.dir / "bag") as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            for c, _, raw in reader.messages(connections=conns):
                yield self.ts.deserialize_cdr(raw, c.msgtype)

    def static(self, child: str) -> np.ndarray:
        """base_link -> ``child`` (the sensor's pose on the body)."""
        for msg in self.messages("/tf_static"):
            for tf in msg.transforms:
                if tf.child_frame_id == child:
                    return _matrix(tf.transform)
        raise KeyError(f"/tf_static has no frame {child!r}")

    def body_poses(self):
        """A function t -> (N, 4, 4) map <- base_link, interpolated from /tf (true pose, 100 Hz)."""
        ts, mats = [], []
        for msg in self.messages("/tf"):
            for tf in msg.transforms:
                ts.append(_stamp(tf.header))
                mats.append(_matrix(tf.transform))
        ts, mats = np.asarray(ts), np.asarray(mats)
        slerp = Slerp(ts, Rotation.from_matrix(mats[:, :3, :3]))

        def at(t):
            t = np.clip(np.atleast_1d(np.asarray(t, np.float64)), ts[0], ts[-1])
            out = np.tile(np.eye(4), (len(t), 1, 1))
            out[:, :3, :3] = slerp(t).as_matrix()
            out[:, :3, 3] = np.column_stack([np.interp(t, ts, mats[:, k, 3]) for k in range(3)])
            return out
        return at

    def lidar_world(self, sensor: str = "lidar"):
        """Per scan: (world points (N, 3), class ids (N,)), each point moved to the map with the
        body pose at its own time (de-skew) and the sensor's extrinsic."""
        ext = self.static(sensor)
        pose_at = self.body_poses()
        for msg in self.messages(f"/{sensor}/points"):
            names = [f.name for f in msg.fields]
            fmt = {7: "<f4", 2: "u1", 4: "<u2", 6: "<u4"}
            dt = np.dtype({"names": names, "formats": [fmt[f.datatype] for f in msg.fields],
                           "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_step})
            rec = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), dt)
            t = _stamp(msg.header) + rec["t"] * 1e-9
            T = pose_at(t) @ ext
            p = np.column_stack([rec["x"], rec["y"], rec["z"]]).astype(np.float64)
            yield np.einsum("nij,nj->ni", T[:, :3, :3], p) + T[:, :3, 3], rec["label"].astype(np.int64)

    def stereo_frames(self, sensor: str = "stereo"):
        """Per frame: dict(t, left, right (uint8 RGB), K (3x3), baseline, instance (uint16), depth
        (true z-depth, m), semantic (class ids), cam_to_world (4x4, the frame's middle sub-frame, from frames.json))."""
        meta = {round(f["t"], 6): np.asarray(f["cam_to_world"]) for f in
                json.loads((self.dir / "frames.json").read_text()) if f["sensor"] == sensor}
        streams = [self.messages(f"/{sensor}/left/image_raw"), self.messages(f"/{sensor}/right/image_raw"),
                   self.messages(f"/{sensor}/right/camera_info"), self.messages(f"/{sensor}/instance"),
                   self.messages(f"/{sensor}/depth"), self.messages(f"/{sensor}/semantic")]
        for left, right, info, inst, depth, sem in zip(*streams):
            t = _stamp(left.header)
            K = np.asarray(info.k, np.float64).reshape(3, 3)
            yield {"t": t, "left": _image(left), "right": _image(right), "K": K,
                   "baseline": float(-np.asarray(info.p)[3] / K[0, 0]), "instance": _image(inst),
                   "depth": _image(depth), "semantic": _image(sem), "cam_to_world": meta[round(t, 6)]}


def _image(msg) -> np.ndarray:
    dt = {"rgb8": (np.uint8, 3), "mono8": (np.uint8, 1), "mono16": (np.uint16, 1), "32FC1": (np.float32, 1)}
    kind, ch = dt[msg.encoding]
    a = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), kind).reshape(msg.height, msg.width, ch)
    return a[..., 0] if ch == 1 else a


@dataclass
class Truth:
    """The twin's own truth: road heights on the collision mesh, each defect's footprint
    (shapely, world XY), depth, type and centre."""

    scene: object
    footprints: dict
    defects: dict

    def height(self, xy: np.ndarray) -> np.ndarray:
        import open3d as o3d

        top = 1e4
        rays = np.zeros((len(xy), 6), np.float32)
        rays[:, :2], rays[:, 2], rays[:, 5] = xy, top, -1.0
        t = self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
        return np.where(np.isfinite(t), top - t, np.nan)


def load_truth(stage: Path) -> Truth:
    import open3d as o3d

    from roadtwin_core.apps.drive.contacts import defect_footprints
    from roadtwin_core.usd.town_reader import load_town

    town = load_town(stage)
    v, f = town.collision_mesh()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(f, np.uint32)))
    defects = {d.id: {"type": d.defect_type, "depth_m": float(d.attributes.get("depthM", np.nan)),
                      "xy": np.asarray(d.attributes["poseXYYaw"][:2], float)}
               for d in town.defects if "poseXYYaw" in d.attributes}
    return Truth(scene, defect_footprints(town), defects)
