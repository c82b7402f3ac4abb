"""The drive as a rerun recording (``drive.rrd``): the map (road outline as line strips, the
defects' outlines, the route), the body's path and pose, every sensor on the one timeline
``sim_time`` (images with their pinhole and pose, LiDAR points coloured by class in the world,
IMU channels as scalars, GNSS fixes), and the wheel-defect contact events as text log lines."""
from __future__ import annotations

import numpy as np


class RrdWriter:
    def __init__(self, path, name: str = "roadtwin drive") -> None:
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(name)
        self.path = str(path)
        self.rec.save(self.path)

    def _time(self, t: float) -> None:
        self.rec.set_time("sim_time", duration=float(t))

    def write_map(self, route_xy: np.ndarray, footprints: dict, z: float) -> None:
        rr = self.rr
        self.rec.log("world/route", rr.LineStrips3D([np.column_stack([route_xy, np.full(len(route_xy), z)])],
                                                    colors=[[80, 160, 255]]), static=True)
        strips = []
        for g in footprints.values():
            for poly in getattr(g, "geoms", [g]):
                xy = np.asarray(poly.exterior.coords)
                strips.append(np.column_stack([xy, np.full(len(xy), z + 0.02)]))
        if strips:
            self.rec.log("world/defects", rr.LineStrips3D(strips, colors=[[255, 60, 60]]), static=True)

    def write_truth(self, t: float, pose: np.ndarray) -> None:
        rr = self.rr
        self._time(t)
        self.rec.log("world/base_link", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))

    def write(self, sensor, msg: dict, pose_at) -> None:
        rr = self.rr
        self._time(msg["t"])
        if sensor.message == "imu":
            for k, a in enumerate("xyz"):
                self.rec.log(f"imu/{sensor.id}/acc_{a}", rr.Scalars(float(msg["linear_acceleration"][k])))
                self.rec.log(f"imu/{sensor.id}/gyro_{a}", rr.Scalars(float(msg["angular_velocity"][k])))
        elif sensor.message == "gnss":
            self.rec.log(f"gnss/{sensor.id}", rr.GeoPoints(lat_lon=[[msg["latitude"], msg["longitude"]]]))
            self.rec.log(f"world/gnss/{sensor.id}", rr.Points3D([msg["truth"]["enu"]], radii=0.1))
        elif sensor.message in ("image", "stereo"):
            k = msg["intrinsics"]
            m = msg["cam_to_world"]
            path = f"world/{sensor.id}"
            self.rec.log(path, rr.Transform3D(translation=m[:3, 3], mat3x3=m[:3, :3]))
            self.rec.log(path, rr.Pinhole(image_from_camera=k.K, resolution=[k.width, k.height],
                                          camera_xyz=rr.ViewCoordinates.RDF))
            self.rec.log(f"{path}/rgb", rr.Image(msg["rgb"]))
            self.rec.log(f"{path}/semantic", rr.SegmentationImage(msg["semantic"]))
        elif sensor.message == "points":
            T = pose_at(msg["t"] + msg["time_offset_s"].astype(np.float64)) @ sensor.extrinsic
            xyz = msg["xyz"].astype(np.float64)
            w = np.einsum("nij,nj->ni", T[:, :3, :3], xyz) + T[:, :3, 3]
            pal = np.array([[128, 128, 128], [60, 60, 60], [255, 255, 255], [255, 0, 0], [255, 160, 0],
                            [0, 200, 0], [0, 120, 255], [200, 0, 200], [0, 200, 200], [150, 100, 50]], np.uint8)
            self.rec.log(f"world/{sensor.id}", rr.Points3D(w, colors=pal[msg["label"] % len(pal)], radii=0.02))

    def write_events(self, events: list[dict]) -> None:
        rr = self.rr
        for e in events:
            self._time(e["t_entry_s"])
            self.rec.log("events", rr.TextLog(f"{e['wheel']} enters {e['defect']} ({e['defect_type']})"))
            self._time(e["t_exit_s"])
            self.rec.log("events", rr.TextLog(f"{e['wheel']} leaves {e['defect']}"))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
