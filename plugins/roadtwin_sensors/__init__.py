"""roadtwin_sensors: the built-in sensor models a drive's rig mounts on the vehicle body.

Registered through the ``roadtwin`` entry-point group as ``sensors = "roadtwin_sensors"``; each
registered sensor type meets :class:`roadtwin_core.contracts.Sensor`: ``name`` (the rig file's
``type``), ``description``, ``Params`` (a dataclass of :func:`roadtwin_core.field`),
``message`` (what its samples are: imu | gnss | image | stereo | points) and
``create(sensor_id, rate_hz, extrinsic, params)`` -> a mounted sensor with ``id``, ``rate_hz``,
``extrinsic`` (4x4, sensor in the body frame) and ``sample(state, world) -> dict``.

``state`` is the vehicle on the drive's clock at ``state.t`` (``pose_at(t)``: 4x4 body-to-world,
vectorised over times; ``velocity_at(t)``; ``imu_truth(offset, t0, t1)``: mean specific force and
body rate at a body point); ``world`` the services of the scene (``render(cameras)`` through the
drive's renderer plugin, ``cast(origins, dirs)`` -> ``{"t", "class_id", "instance"}``,
``class_names``). Built-ins: ``imu``, ``gnss``, ``camera``, ``stereo``, ``lidar``. numpy only
(opencv for the cameras' motion blur, open3d for the stand-alone scan simulator in
:mod:`.scan_patterns`). What they share (the mount, the registered type, the LiDAR's returns)
is in :mod:`._mount`.

Also here, as a sensor model: the Livox rosette scan simulator over a known mesh
(:func:`simulate_scans`, :class:`RosetteScanner`, :func:`path_poses`; the LiDAR reconstructor's
tests and ``bench/lidar.py`` scan their ground truth with it).
"""
from __future__ import annotations

from roadtwin_core import hookimpl

from .camera import CameraParams, MonoCamera, StereoPair
from .gnss import Gnss, GnssParams, enu_to_geodetic
from .imu import Imu, ImuParams
from .lidar import Lidar, LidarParams
from .scan_patterns import (RosetteScanner, cast, mid360_directions, path_poses, raycasting_scene, rosette_directions,
                            simulate_scans, vertical_heights)

__all__ = ["Imu", "ImuParams", "Gnss", "GnssParams", "MonoCamera", "StereoPair", "CameraParams", "Lidar",
           "LidarParams", "enu_to_geodetic", "RosetteScanner", "cast", "mid360_directions", "path_poses",
           "raycasting_scene", "rosette_directions", "simulate_scans", "vertical_heights"]


@hookimpl
def roadtwin_register_sensors(register):
    for thing in (Imu(), Gnss(), MonoCamera(), StereoPair(), Lidar()):
        register(thing)
