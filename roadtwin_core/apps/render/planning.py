"""Each frame's job decided before any is rendered: its camera, ego lane, look and camera model —
on forked processes when there are many frames.

Why: a frame's plan depends on ``(seed, i)`` and the stage alone (the view sampler's draws, the
randomizer's), but costs ~0.7 ms of Python a frame. On a GPU that renders 300 frames/s, planning
3,000 frames in one process is a fifth of the run. So frames are planned in blocks
(:meth:`FramePlanner.block`), spread over a pool forked from this process (the town, its lanes and
ground sampler are inherited, not shipped) and gathered in order: the jobs are those of planning
every frame here, in one block, whatever the number of processes. On a GPU the blocks go to the
frame sink's finishing processes (forked inside :func:`forking`, before the device is touched) while
this process uploads the scene (``meanwhile``): no second pool, and the upload is off the setup's path.
"""
from __future__ import annotations

import multiprocessing
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Any

from ...params import check_params
from ...render import Camera, StereoCamera
from ...render.randomize import Ranges, draw
from .cameras import CameraPlan, DefectViews, ego_lane_points, with_ego_lanes
from .pipeline import FrameJob

__all__ = ["BLOCK", "PARALLEL_FROM", "FramePlanner", "forking", "frame_jobs", "plan_all"]

BLOCK = 128                 # frames a task
PARALLEL_FROM = 1024        # fewer frames are planned in this process: forking a pool costs ~0.1 s

_PLANNER: "FramePlanner | None" = None      # what the forked pool's processes plan with


@dataclass
class FramePlanner:
    """What planning frames needs: the cameras (a whole :class:`CameraPlan`, or :class:`DefectViews`
    drawn per block), the ego lane's chained lanes (None: no ego-lane class), the look table
    (``--randomize``: ``LookTable`` of the split mesh, else None), the render parameters and seed."""

    cameras: CameraPlan | DefectViews
    params: Any
    seed: int
    table: Any = None
    ranges: Ranges | None = None
    chained: list | None = None
    lane_width: float = 3.5

    def block(self, start: int, stop: int) -> tuple[CameraPlan, list[FrameJob], dict]:
        """Frames ``start .. stop - 1``: their camera plan (without lane objects), jobs and seconds per phase."""
        t0 = time.perf_counter()
        plan = self.cameras.block(start, stop)
        lane_xy = [None] * len(plan.poses)
        if self.chained is not None:
            plan = with_ego_lanes(plan, self.chained, self.lane_width)
            lane_xy = ego_lane_points(plan)
        t1 = time.perf_counter()
        jobs = frame_jobs(plan, start, self.params, self.seed, lane_xy, self.table, self.ranges)
        return replace(plan, lane_of=[]), jobs, {"view_sampling": t1 - t0, "randomize": time.perf_counter() - t1}


def frame_jobs(plan: CameraPlan, start: int, params, seed: int, lane_xy: list, table=None,
               ranges: Ranges | None = None) -> list[FrameJob]:
    """One FrameJob per camera of ``plan`` (frames ``start ..``). With a look ``table`` each frame
    draws its look and camera model from ``(seed, i)`` alone (``ranges``: what it draws from,
    default ``Ranges()``), so every executor renders the same frames."""
    cams = [Camera(plan.intrinsics, p) for p in plan.poses]
    if plan.stereo:
        cams = [StereoCamera(c, plan.baseline_m) for c in cams]
    ranges = ranges or Ranges()
    jobs = []
    for k, cam in enumerate(cams):
        i = start + k
        record: dict = {}
        if plan.view_records:
            record["view"] = plan.view_records[k]
        if plan.lane_of and plan.lane_of[k] is not None:
            lane, s = plan.lane_of[k]
            record.setdefault("view", {})["ego_lane"] = {"lane": lane.id, "s_m": round(s, 3)}
        if table is not None:
            fr = draw(seed, i, base=params, ranges=ranges)
            look = table.look(fr.look)
            record["randomization"] = {**fr.as_dict(), "applied": look.applied}
            jobs.append(FrameJob(i, cam, check_params(fr.render, "render"), look, fr.effects, lane_xy[k], record))
        else:
            jobs.append(FrameJob(i, cam, params, None, None, lane_xy[k], record))
    return jobs


def _usable_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _planned_block(block: tuple[int, int]):
    return _PLANNER.block(*block)


@contextmanager
def forking(planner: "FramePlanner"):
    """Processes forked inside can plan ``planner``'s blocks: pass their executor to :func:`plan_all`
    (``pool``) within the same block."""
    global _PLANNER
    before, _PLANNER = _PLANNER, planner
    try:
        yield
    finally:
        _PLANNER = before


def plan_all(planner: FramePlanner, frames: int, *, processes: int | None = None,
             parallel_from: int | None = None, pool=None, meanwhile=None) -> tuple[CameraPlan, list[FrameJob], dict]:
    """Every frame planned: (the camera plan of all frames, their jobs, seconds per phase summed
    over processes). ``pool``: an executor of processes forked inside :func:`forking` of this
    planner, else a pool of ``processes`` (default: the cores this process may use) is forked here;
    fewer than ``parallel_from`` (default ``PARALLEL_FROM``) frames, or one process, plan here.
    ``meanwhile``: called here while the blocks are planned elsewhere (after planning otherwise)."""
    parallel_from = PARALLEL_FROM if parallel_from is None else parallel_from
    meanwhile = meanwhile or (lambda: None)
    blocks = [(a, min(a + BLOCK, frames)) for a in range(0, frames, BLOCK)] or [(0, 0)]
    n_proc = min(processes or _usable_cores(), len(blocks))
    if pool is not None and _PLANNER is not planner:
        raise ValueError("plan_all: the pool's processes were not forked inside forking(planner)")
    if frames < parallel_from or (pool is None and (n_proc < 2 or multiprocessing.current_process().daemon)):
        parts = [planner.block(a, b) for a, b in blocks]       # a pool's worker: no children
        meanwhile()
    elif pool is not None:
        futures = [pool.submit(_planned_block, b) for b in blocks]
        try:
            meanwhile()
            parts = [f.result() for f in futures]      # in order: a bad frame's error is the first one's
        finally:
            for f in futures:
                f.cancel()
    else:
        with forking(planner), multiprocessing.get_context("fork").Pool(n_proc) as forked:
            results = forked.imap(_planned_block, blocks)
            meanwhile()
            # in order: a bad frame's error is the first one's, as when planned here
            parts = list(results)
    plans = [p for p, _, _ in parts]
    plan = replace(plans[0], poses=[x for p in plans for x in p.poses],
                   view_records=[x for p in plans for x in p.view_records], lane_of=[])
    phases = {k: sum(t[k] for _, _, t in parts) for k in ("view_sampling", "randomize")}
    return plan, [j for _, jobs, _ in parts for j in jobs], phases
