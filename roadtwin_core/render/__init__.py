"""Perception data from composed towns: cameras and poses, the renderer contract's data
(``RenderMesh`` in, ``Frame`` out), an event camera simulator and a torch ``Dataset`` over a
render's output. Renderers themselves are plugins (``roadtwin_register_renderers``); what
``roadtwin render`` does (frame jobs, dataset writers) is ``roadtwin_core.apps.render``. Nothing
here imports USD at module level (``stage_lanes`` does, when called) or torch
(``roadtwin_core.datasets.render_output`` does, when its class is first used).
"""
from .cameras import (Camera, Intrinsics, camera_matrix, KeepOut, Lane, StereoCamera, lane_keep_out, lane_trajectory, load_poses_file,
                      look_from, rotation_ypr, sample_lane_poses)
from .events import EventSimulator, luminance
from .frames import WEATHERS, Frame, RenderParams
from .scene import (BASE_CLASSES, DEFAULT_MATERIAL, IGNORE_INDEX, MARKING_CLASS, GroundSampler, RenderMaterial,
                    RenderMesh, build_render_mesh, class_names, stage_lanes)
from .tonemap import to_srgb8

__all__ = [
    "Camera", "Intrinsics", "KeepOut", "camera_matrix", "Lane", "StereoCamera", "lane_keep_out", "lane_trajectory", "load_poses_file",
    "look_from",
    "rotation_ypr", "sample_lane_poses", "EventSimulator", "luminance", "WEATHERS", "Frame", "RenderParams",
    "BASE_CLASSES", "DEFAULT_MATERIAL", "IGNORE_INDEX", "MARKING_CLASS", "GroundSampler", "RenderMaterial",
    "RenderMesh",
    "build_render_mesh", "class_names", "stage_lanes", "to_srgb8",
]
