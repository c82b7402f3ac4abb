"""Where a render's cameras come from, first that applies: a ``--poses`` file (checked against the
road: no camera below it or inside geometry), ``--views defects:SHARE`` (the view sampler),
the stage's ``UsdGeom.Camera`` prims, random lane poses (also ``--views random``). Sampled poses
keep clear of the vehicles a town's props stand in its lanes. Also the lane
each camera drives in, for datasets with an ego-lane class.

Sampled views are drawn per frame from ``(seed, i)`` alone, so they are planned in blocks
(:class:`DefectViews`), which ``planning`` spreads over processes; every other source is cheap
and planned whole (:meth:`CameraPlan.block` slices it)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ...errors import RoadtwinError
from ...render import lane_keep_out, load_poses_file, sample_lane_poses
from ...render.rig_usd import read_stage_cameras
from ...render.view_sampler import ViewRig, chain_lanes, defect_targets, lane_ahead, sample_views
from .lanes import nearest_lane
from .options import DEFECT_DISTANCE_M, Rig, ViewSpec

__all__ = ["CameraPlan", "DefectViews", "ego_lane_points", "plan_cameras", "with_ego_lanes"]


@dataclass
class CameraPlan:
    """The frames' camera poses (camera-to-world, OpenCV axes) and what the dataset records of them."""

    poses: list
    source: str                       # meta.json's "poses": a file, defects:SHARE, stage cameras, lanes
    intrinsics: object                # Intrinsics of every frame
    stereo: bool
    baseline_m: float
    view_records: list[dict] = field(default_factory=list)   # per frame: the view sampler's or camera prim's record
    lane_of: list = field(default_factory=list)              # per frame: (chained lane, s) or None; [] if unknown

    @property
    def frames(self) -> int:
        return len(self.poses)

    def block(self, start: int, stop: int) -> "CameraPlan":
        """Frames ``start .. stop - 1`` of this plan."""
        return dataclasses.replace(self, poses=self.poses[start:stop], view_records=self.view_records[start:stop],
                                   lane_of=self.lane_of[start:stop])


@dataclass
class DefectViews:
    """``--views defects:SHARE``, drawn when asked: :meth:`block` samples frames ``start .. stop - 1``
    (the view sampler's frame ``i`` depends on ``(seed, i)`` alone, so blocks give the views of
    sampling all frames at once). Same attributes as :class:`CameraPlan` but the per-frame lists."""

    chained: list
    targets: object                   # view_sampler.DefectTargets
    ground: object                    # GroundSampler
    sampler: dict                     # sample_views' keywords
    frames: int
    source: str
    intrinsics: object
    stereo: bool
    baseline_m: float

    def block(self, start: int, stop: int) -> CameraPlan:
        sampled = sample_views(self.chained, self.targets, self.ground, stop - start, start=start, **self.sampler)
        by_id = {lane.id: lane for lane in self.chained}
        records = [{k: v for k, v in view.as_dict().items() if k not in ("index", "cam_to_world")} for view in sampled]
        return CameraPlan([v.cam_to_world for v in sampled], self.source, self.intrinsics, self.stereo, self.baseline_m,
                          records, [(by_id[v.lane_id], v.s_m) for v in sampled])


def plan_cameras(stage: Path, town, lanes: list, ground: Callable, rig: Rig, intrinsics, *, frames: int,
                 poses: str | Path | None, views: ViewSpec, seed: int, min_clearance_m: float) -> CameraPlan | DefectViews:
    """The cameras of ``frames`` frames (sampled views: drawn per block, :class:`DefectViews`).
    ``ground()``: the stage's ground sampler (built on first use)."""
    if poses is not None:
        pose_list = load_poses_file(poses)[:frames]
        _check_clearance(pose_list, ground(), str(poses), min_clearance_m)
        return CameraPlan(pose_list, str(poses), intrinsics, rig.stereo, rig.baseline_m)
    if views.kind == "defects":
        return _aimed_at_defects(stage, town, lanes, ground(), rig, intrinsics, frames, views, seed)
    stage_cams = [] if views.kind != "none" else read_stage_cameras(
        stage, (rig.width, rig.height_px) if rig.size_given else None)
    if rig.preset is not None:
        stage_cams = [c for c in stage_cams if c.rig == rig.preset.name]
    if stage_cams:
        return _stage_cameras(stage, stage_cams[:frames], rig)
    if lanes:
        kw = {}
        if rig.preset is not None or rig.pitch_deg is not None:       # a rig: its pitch, small jitter
            p0 = rig.pitch_deg if rig.pitch_deg is not None else -15.0
            kw = {"pitch_deg": (p0 - 2.0, p0 + 2.0), "yaw_jitter_deg": 3.0, "roll_jitter_deg": 1.0}
        pose_list = sample_lane_poses(lanes, frames, np.random.default_rng(seed), ground(),
                                      height=rig.mount_height_m, keep_out=lane_keep_out(town), **kw)
        return CameraPlan(pose_list, "lanes", intrinsics, rig.stereo, rig.baseline_m)
    raise RoadtwinError(f"{stage}: no cameras or poses: the stage has no driving lane centerlines "
                        "(roadtwin:segment:centerline), no camera prims and no --poses file was given")


def _check_clearance(pose_list, ground, source: str, min_clearance_m: float) -> None:
    """A camera below the road or closer to it than the renderer's clearance is an error, named."""
    z_road = ground(np.array([p[:3, 3][:2] for p in pose_list]))
    for k, (p, z) in enumerate(zip(pose_list, z_road)):
        where = f"{source}: camera {k} at ({p[0, 3]:.2f}, {p[1, 3]:.2f}, {p[2, 3]:.2f})"
        if np.isfinite(z) and p[2, 3] < z:
            raise RoadtwinError(f"{where} is below the road surface (z = {z:.2f} there)")
        if np.isfinite(z) and p[2, 3] < z + min_clearance_m:
            raise RoadtwinError(f"{where} is inside geometry: {p[2, 3] - z:.3f} m above the road "
                                f"(minimum clearance {min_clearance_m} m)")


def _aimed_at_defects(stage, town, lanes, ground, rig: Rig, intrinsics, frames, views: ViewSpec, seed) -> DefectViews:
    vrig = ViewRig(mount_height_m=rig.mount_height_m, hfov_deg=rig.hfov_deg, width_px=rig.width, height_px=rig.height_px,
                   **({"pitch_deg": rig.pitch_deg} if rig.pitch_deg is not None else {}))
    chained = chain_lanes(lanes)      # what view_sampler.stage_views does, without re-reading the stage
    if not chained:
        raise RoadtwinError(f"{stage}: no driving lane centrelines (roadtwin:segment:centerline) to place views on")
    share, background = views.share, views.background
    near_m, far_m = views.distance_m
    source = f"defects:{share}" + (":clear" if background == "clear" else "")
    if views.distance_m != DEFECT_DISTANCE_M:
        source += f":{near_m:g}-{far_m:g}"
    sampler = {"rig": vrig, "share": share, "seed": seed, "background": background, "keep_out": lane_keep_out(town),
               "near_m": near_m, "far_m": far_m}
    return DefectViews(chained, defect_targets(town), ground, sampler, frames, source, intrinsics, rig.stereo,
                       rig.baseline_m)


def _stage_cameras(stage, cams, rig: Rig) -> CameraPlan:
    """The stage's camera prims of one rig: one image size and focal length for the whole dataset."""
    sizes = {(c.intrinsics.width, c.intrinsics.height, round(c.intrinsics.fx, 6), round(c.intrinsics.fy, 6)) for c in cams}
    if len(sizes) > 1:
        raise RoadtwinError(f"{stage}: its cameras differ in image size or focal length "
                            f"({', '.join(sorted({c.rig for c in cams}))}); pick one rig with --rig")
    stereo, baseline = (True, cams[0].baseline_m) if cams[0].baseline_m else (rig.stereo, rig.baseline_m)
    return CameraPlan([c.cam_to_world for c in cams], "stage cameras", cams[0].intrinsics, stereo, baseline,
                      [{"camera_prim": c.path, "rig": c.rig} for c in cams])


def with_ego_lanes(plan: CameraPlan, chained: list, lane_width: float) -> CameraPlan:
    """``plan`` with the lane each camera drives in: the view sampler's lane where it placed the
    camera, else the nearest of the ``chained`` lanes (``chain_lanes``) within ``lane_width``
    heading the camera's way (or None)."""
    if plan.lane_of or not plan.poses:
        return plan
    return dataclasses.replace(plan, lane_of=[nearest_lane(chained, p, lane_width) for p in plan.poses])


def ego_lane_points(plan: CameraPlan) -> list:
    """Per frame, the centreline ahead of the camera's lane (the ego-lane class), or None."""
    return [lane_ahead(lane, s) if lane is not None else None
            for lane, s in ((x if x is not None else (None, 0.0)) for x in plan.lane_of)]
