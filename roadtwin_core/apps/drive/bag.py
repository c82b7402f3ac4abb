"""The drive as a ROS 2 bag in MCAP storage (rosbags; no ROS install needed), standard messages:

=====================================  =============================================================
topic                                  message
=====================================  =============================================================
/tf_static                             tf2_msgs/TFMessage: base_link -> each sensor (and optical frames)
/tf                                    tf2_msgs/TFMessage: map -> base_link (true body pose, 100 Hz)
/ground_truth/odom                     nav_msgs/Odometry: true body pose and velocity (100 Hz)
/ID/imu                                sensor_msgs/Imu
/ID/fix                                sensor_msgs/NavSatFix
/ID/image_raw, /ID/camera_info         sensor_msgs/Image rgb8 (or CompressedImage), CameraInfo
/ID/left/..., /ID/right/...            the same for a stereo pair (right P[0,3] = -fx * baseline)
/ID/semantic, /ID/instance, /ID/depth  ground truth per frame: mono8 class ids, mono16 defect
                                       instances, 32FC1 z-depth (m) (left view for a stereo pair)
/ID/points                             sensor_msgs/PointCloud2: x y z (float32), reflectivity (uint8),
                                       t (uint32 ns since the frame stamp), label, instance (uint16)
=====================================  =============================================================

Stamps: the drive's clock plus ``epoch_s`` (default 1.7e9 s, so tools that dislike time 0 are
happy); every message's header stamp is the sample's time on the one clock.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

EPOCH_S = 1_700_000_000


class BagWriter:
    def __init__(self, path, sensors, epoch_s: float = EPOCH_S, compressed: bool = False) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.T = self.ts.types
        self.epoch = epoch_s
        self.compressed = compressed
        self.writer = Writer(path, version=8, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.conns: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self.sensors = {s.id: s for s in sensors}

    # ------------------------------------------------------------------ helpers
    def _conn(self, topic: str, msgtype: str):
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        return self.conns[topic]

    def _write(self, topic: str, msgtype: str, msg, t: float) -> None:
        conn = self._conn(topic, msgtype)
        self.writer.write(conn, self._ns(t), self.ts.serialize_cdr(msg, msgtype))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _ns(self, t: float) -> int:
        # integer epoch + the clock's nanoseconds: (epoch + t) * 1e9 in float64 would lose ~100 ns
        return int(round(self.epoch * 1e9)) + int(round(t * 1e9))

    def _header(self, t: float, frame: str):
        ns = self._ns(t)
        return self.T["std_msgs/msg/Header"](stamp=self.T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000,
                                                                                       nanosec=ns % 1_000_000_000),
                                             frame_id=frame)

    def _tf(self, t, parent, child, m):
        T = self.T
        q = _quat(m[:3, :3])
        return T["geometry_msgs/msg/TransformStamped"](
            header=self._header(t, parent), child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])),
                rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])))

    # ------------------------------------------------------------------ static / truth
    def write_static(self, sensors) -> None:
        tfs = []
        for s in sensors:
            tfs.append(self._tf(0.0, "base_link", s.id, s.extrinsic))
            if s.message in ("image", "stereo"):
                opt = np.linalg.inv(s.extrinsic) @ s.optical
                tfs.append(self._tf(0.0, s.id, f"{s.id}_optical", opt))
        self._write("/tf_static", "tf2_msgs/msg/TFMessage", self.T["tf2_msgs/msg/TFMessage"](transforms=tfs), 0.0)

    def write_truth(self, t: float, pose: np.ndarray, vel_world: np.ndarray, omega_body: np.ndarray) -> None:
        T = self.T
        self._write("/tf", "tf2_msgs/msg/TFMessage",
                    T["tf2_msgs/msg/TFMessage"](transforms=[self._tf(t, "map", "base_link", pose)]), t)
        q = _quat(pose[:3, :3])
        v_b = pose[:3, :3].T @ vel_world
        cov = np.zeros(36)
        odom = T["nav_msgs/msg/Odometry"](
            header=self._header(t, "map"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3])),
                orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])), covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                linear=_v3(T, v_b), angular=_v3(T, omega_body)), covariance=cov))
        self._write("/ground_truth/odom", "nav_msgs/msg/Odometry", odom, t)

    # ------------------------------------------------------------------ sensors
    def write(self, sensor, msg: dict) -> None:
        kind = sensor.message
        if kind == "imu":
            self._imu(sensor, msg)
        elif kind == "gnss":
            self._gnss(sensor, msg)
        elif kind == "image":
            self._image(f"/{sensor.id}", f"{sensor.id}_optical", msg, msg["rgb"], msg["intrinsics"], 0.0)
        elif kind == "stereo":
            self._image(f"/{sensor.id}/left", f"{sensor.id}_optical", msg, msg["rgb"], msg["intrinsics"], 0.0)
            self._image(f"/{sensor.id}/right", f"{sensor.id}_optical", None, msg["rgb_right"], msg["intrinsics"],
                        msg["baseline_m"])
        elif kind == "points":
            self._points(sensor, msg)

    def _imu(self, sensor, m):
        T = self.T
        q = m["orientation"]
        msg = T["sensor_msgs/msg/Imu"](
            header=self._header(m["t"], sensor.id),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            orientation_covariance=np.zeros(9), angular_velocity=_v3(T, m["angular_velocity"]),
            angular_velocity_covariance=np.diag([m["gyro_var"]] * 3).ravel(),
            linear_acceleration=_v3(T, m["linear_acceleration"]),
            linear_acceleration_covariance=np.diag([m["accel_var"]] * 3).ravel())
        self._write(f"/{sensor.id}/imu", "sensor_msgs/msg/Imu", msg, m["t"])

    def _gnss(self, sensor, m):
        T = self.T
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=self._header(m["t"], sensor.id),
            status=T["sensor_msgs/msg/NavSatStatus"](status=m["status"], service=1),
            latitude=m["latitude"], longitude=m["longitude"], altitude=m["altitude"],
            position_covariance=np.asarray(m["covariance"], np.float64).ravel(), position_covariance_type=2)
        self._write(f"/{sensor.id}/fix", "sensor_msgs/msg/NavSatFix", msg, m["t"])

    def _image(self, base, frame, m, rgb, k, baseline):
        T, t = self.T, None
        t = self._last_t if m is None else m["t"]
        self._last_t = t
        h, w = rgb.shape[:2]
        hdr = self._header(t, frame)
        if self.compressed:
            import cv2

            ok, buf = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])
            self._write(f"{base}/image_raw/compressed", "sensor_msgs/msg/CompressedImage",
                        T["sensor_msgs/msg/CompressedImage"](header=hdr, format="rgb8; jpeg compressed bgr8",
                                                             data=np.frombuffer(buf.tobytes(), np.uint8)), t)
        else:
            self._write(f"{base}/image_raw", "sensor_msgs/msg/Image", _img(T, hdr, rgb, "rgb8", 3), t)
        P = np.array([[k.fx, 0, k.cx, -k.fx * baseline], [0, k.fy, k.cy, 0], [0, 0, 1, 0]], np.float64)
        info = T["sensor_msgs/msg/CameraInfo"](
            header=hdr, height=h, width=w, distortion_model="plumb_bob", d=np.zeros(5), k=k.K.ravel(),
            r=np.eye(3).ravel(), p=P.ravel(), binning_x=0, binning_y=0,
            roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
        self._write(f"{base}/camera_info", "sensor_msgs/msg/CameraInfo", info, t)
        if m is not None:
            root = base.rsplit("/left", 1)[0]
            self._write(f"{root}/semantic", "sensor_msgs/msg/Image", _img(T, hdr, m["semantic"].astype(np.uint8), "mono8", 1), t)
            self._write(f"{root}/instance", "sensor_msgs/msg/Image",
                        _img(T, hdr, m["instance"].astype(np.uint16), "mono16", 2), t)
            self._write(f"{root}/depth", "sensor_msgs/msg/Image", _img(T, hdr, m["depth"].astype(np.float32), "32FC1", 4), t)

    def _points(self, sensor, m):
        T = self.T
        PF = T["sensor_msgs/msg/PointField"]
        n = len(m["xyz"])
        dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("reflectivity", "u1"), ("pad", "u1"),
                       ("label", "<u2"), ("instance", "<u2"), ("pad2", "<u2"), ("t", "<u4")])
        rec = np.zeros(n, dt)
        rec["x"], rec["y"], rec["z"] = m["xyz"][:, 0], m["xyz"][:, 1], m["xyz"][:, 2]
        rec["reflectivity"], rec["label"], rec["instance"] = m["reflectivity"], m["label"], m["instance"]
        rec["t"] = np.round(m["time_offset_s"] * 1e9).astype(np.uint32)
        fields = [PF(name="x", offset=0, datatype=7, count=1), PF(name="y", offset=4, datatype=7, count=1),
                  PF(name="z", offset=8, datatype=7, count=1), PF(name="reflectivity", offset=12, datatype=2, count=1),
                  PF(name="label", offset=14, datatype=4, count=1), PF(name="instance", offset=16, datatype=4, count=1),
                  PF(name="t", offset=20, datatype=6, count=1)]
        msg = T["sensor_msgs/msg/PointCloud2"](header=self._header(m["t"], sensor.id), height=1, width=n, fields=fields,
                                               is_bigendian=False, point_step=dt.itemsize, row_step=dt.itemsize * n,
                                               data=rec.view(np.uint8).ravel(), is_dense=True)
        self._write(f"/{sensor.id}/points", "sensor_msgs/msg/PointCloud2", msg, m["t"])

    def close(self) -> None:
        self.writer.close()


def _v3(T, v):
    return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _img(T, hdr, a, enc, bpp):
    a = np.ascontiguousarray(a)
    h, w = a.shape[:2]
    return T["sensor_msgs/msg/Image"](header=hdr, height=h, width=w, encoding=enc, is_bigendian=0, step=w * bpp,
                                      data=a.view(np.uint8).ravel())


def _quat(R):
    return [float(v) for v in Rotation.from_matrix(np.asarray(R)[:3, :3]).as_quat()]   # x y z w
