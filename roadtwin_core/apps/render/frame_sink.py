"""Frames into the dataset, in frame order, finished and written by a pool of workers.

Why: once the ray casting runs on a GPU, a frame's CPU work (the camera model's noise and JPEG,
the ego lane, the class map, PNG encoding and file writes) is what limits a render. On a GPU
device the main process only drives the renderer (:func:`render_in_process`; with a renderer
that finishes frames on the device, ``device_frames``, the camera model and labels run there too
and the pool only JPEG-encodes, grows thin classes and writes) and a pool finishes and writes the
frames: processes forked before the scene goes to the device (``processes``: no
GIL between them; each gets a frame's host arrays and returns its records), or threads (the
serial executor). With a CPU process pool (the renderer's workers finish the frames) the files
are written here on threads. Either way :meth:`DatasetWriter.commit` records the frames in frame
order, so the bytes depend neither on the pool nor its size (frame ``i`` depends only on
``(seed, i)``, see ``pipeline``).

Each frame's phases (``FrameOut.timings``: prepare, render, sensor, labels; write here) are
summed in :attr:`FrameSink.phases` (seconds of worker time), what ``bench/render_throughput.py``
prints.
"""
from __future__ import annotations

import mmap
import multiprocessing
import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ...errors import RoadtwinError
from .device_frames import encode_device_frame, finish_on_device, render_on_device
from .pipeline import FrameJob, FrameOut, RenderContext, finish_frame, prepared_scene, render_views

__all__ = ["FrameSink", "render_in_process"]

_SHARED: tuple | None = None        # (context, dataset writer): what finishing workers use (inherited by fork)
_RING: "FrameRing | None" = None     # device-finished frames' arrays on their way to a worker (inherited by fork)


class FrameRing:
    """Slots of anonymous shared memory, mapped before the pool forks, through which a device-
    finished frame's arrays reach a finishing process: the main process copies them into slot
    ``k % slots`` and sends the slot's layout. Why: pickling ~2 MB a frame into the pool's pipe
    took the main process ~1.5 ms a frame, the rate's bound once the GPU rendered in 2.2 ms.
    A slot is reused only after its frame is committed: the sink keeps at most ``2 * workers``
    frames in flight, so ``2 * workers + 2`` slots suffice."""

    def __init__(self, slot_bytes: int, slots: int):
        self.slot_bytes, self.slots = int(slot_bytes), int(slots)
        self.buf = mmap.mmap(-1, self.slot_bytes * self.slots)     # MAP_SHARED | MAP_ANONYMOUS

    def put(self, k: int, arrays: dict) -> list | None:
        """Copy ``arrays`` (name -> ndarray) into frame ``k``'s slot; their layout, or None when
        they do not fit (nothing is written then; they travel pickled)."""
        start = (k % self.slots) * self.slot_bytes
        offsets, at = [], start
        for a in arrays.values():
            offsets.append(at)
            at += -(-a.nbytes // 64) * 64                     # 64-byte aligned
        if at > start + self.slot_bytes:
            return None
        layout = []
        for (name, a), off in zip(arrays.items(), offsets):
            np.ndarray(a.shape, a.dtype, buffer=self.buf, offset=off)[...] = a
            layout.append((name, a.shape, a.dtype.str, off))
        return layout

    def get(self, layout: list) -> dict:
        """The arrays of a slot, as views of the shared memory (valid until the frame commits)."""
        return {name: np.ndarray(shape, np.dtype(dtype), buffer=self.buf, offset=at) for name, shape, dtype, at in layout}

    def close(self) -> None:
        self.buf.close()


def ring_for(cameras, workers: int) -> FrameRing | None:
    """A ring for the frames of ``cameras`` (a camera plan: mono cameras of one size are what the
    device finishes): rgb8, labels, depth and instance ids, 12 bytes a pixel, with room for alignment."""
    if cameras.stereo:                  # stereo pairs are not finished on the device
        return None
    return FrameRing(cameras.intrinsics.width * cameras.intrinsics.height * 12 + 4096, 2 * workers + 2)


@dataclass
class SceneDevice:
    """What ``finish_frame`` reads of a prepared scene (the scene itself stays in the main process)."""

    backend: str | None
    device: str | None


class FrameSink:
    """Finishes and writes frames on ``workers`` threads or forked processes, commits them in order.
    ``cameras``: the camera plan (its frame size; the frames' jobs come with :meth:`expect`)."""

    def __init__(self, ctx: RenderContext, writer, cameras, workers: int, processes: bool,
                 report: Callable[[str, int, int], None]):
        global _SHARED, _RING
        self.writer, self.report = writer, report
        self.jobs: list[FrameJob] = []
        self.workers = max(1, int(workers))
        _SHARED = (ctx, writer)
        _RING = ring_for(cameras, self.workers) if processes else None
        if processes:
            self.pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("fork"))
            self.pool.submit(int).result()      # fork every worker now, before the device is touched
        else:
            self.pool = ThreadPoolExecutor(self.workers, thread_name_prefix="render-finish")
        self.processes = processes
        self.pending: deque[Future] = deque()
        self.early: dict[int, Future] = {}      # put_at: frames written before every earlier one came
        self.shards: list[dict] = []            # gpu_shards: what each GPU's task rendered
        self.shares: list[dict] = []
        self.backend = self.device = None
        self.phases: dict[str, float] = {}

    def expect(self, jobs: list[FrameJob]) -> None:
        """The frames to come, in order (their records are committed with them)."""
        self.jobs = jobs

    # ----------------------------------------------------------------- in
    def finish(self, job: FrameJob, rendered: tuple, scene) -> None:
        """A rendered frame (:func:`render_views`): finished and written by the pool."""
        if self.processes:
            rendered = travelling(_SHARED[0], rendered)
        dev = SceneDevice(getattr(scene, "backend", None), getattr(scene, "device", None))
        self._submit(_finish_and_write, job, rendered, dev)

    def put(self, out: FrameOut) -> None:
        """A finished frame (from a renderer's worker): written by the pool."""
        self._submit(_write, out)

    def put_device(self, job: FrameJob, out: FrameOut) -> None:
        """A frame finished on the device (``device_frames``): encoded and written by the pool;
        to a process pool its arrays go through the shared ring."""
        if _RING is not None:
            f = out.frame
            layout = _RING.put(self._next_index(),
                               {"rgb8": out.rgb8, "semantic": f.semantic, "depth": f.depth, "instance": f.instance})
            if layout is not None:
                out = replace(out, rgb8=None, frame=replace(f, semantic=None, depth=None, instance=None))
                self._submit(_encode_and_write_shared, job, out, layout)
                return
        self._submit(_encode_and_write, job, out)

    def put_at(self, k: int, out: FrameOut) -> None:
        """Finished frame ``k``, arriving in any order (``gpu_shards``: one shard a GPU): written by
        the pool now, committed once every earlier frame is. Blocks while too many writes run.
        A frame whose files were placed in the writer's folder already (``EncodedFrame.placed``)
        needs no writing: it is taken here, without the pool."""
        if out.encoded is not None and out.encoded.placed:
            self.early[k] = Future()
            self.early[k].set_result(_write(k, out))
        else:
            self.early[k] = self.pool.submit(_write, k, out)
        while len(self.shares) in self.early and self.early[len(self.shares)].done():
            self.pending.append(self.early.pop(len(self.shares)))
            self._commit_oldest()
        running = [f for f in self.early.values() if not f.done()]
        if len(running) > 2 * self.workers:
            wait(running, return_when=FIRST_COMPLETED)

    def _next_index(self) -> int:
        """The index the next submitted frame gets (frames committed and in flight before it)."""
        return len(self.shares) + len(self.pending)

    def _submit(self, fn, *args) -> None:
        """Blocks while too many frames are in flight (memory stays bounded), committing the oldest."""
        k = self._next_index()
        self.pending.append(self.pool.submit(fn, k, *args))
        while len(self.pending) > 2 * self.workers or (self.pending and self.pending[0].done()):
            self._commit_oldest()

    # ----------------------------------------------------------------- out
    def _commit_oldest(self) -> None:
        out, written, spent = self.pending.popleft().result()
        t0 = time.perf_counter()
        k = len(self.shares)
        self.writer.commit(written, {**self.jobs[k].record,
                                     "defect_share": {c: round(v, 6) for c, v in out.defect_share.items()}})
        self.shares.append(out.defect_share)
        self.backend, self.device = out.backend, out.device
        for name, seconds in {**out.timings, **spent, "commit": time.perf_counter() - t0}.items():
            self.phases[name] = self.phases.get(name, 0.0) + seconds
        self.report("render", len(self.shares), len(self.jobs))

    def close(self) -> None:
        """Commit every frame still in flight, then stop the pool."""
        try:
            while self.pending or self.early:
                if not self.pending:
                    if len(self.shares) not in self.early:
                        raise RoadtwinError(f"frame {len(self.shares)} was never rendered")
                    self.pending.append(self.early.pop(len(self.shares)))
                self._commit_oldest()
        finally:
            self.shutdown()

    def shutdown(self) -> None:
        global _SHARED, _RING
        for fut in [*self.pending, *self.early.values()]:
            fut.cancel()
        self.pool.shutdown(wait=True)
        if _RING is not None:
            _RING.close()
        _SHARED = _RING = None


def travelling(ctx: RenderContext, rendered: tuple) -> tuple:
    """A rendered frame (:func:`render_views`) without what finishing drops anyway (faces;
    normals unless asked for): it need not travel to a finishing process."""
    frame, _ = rendered
    frame.face = None
    if not ctx.normals:
        frame.normal = None
    return rendered


def _finish_and_write(k: int, job: FrameJob, rendered: tuple, dev: SceneDevice):
    out = finish_frame(_SHARED[0], dev, job, rendered)
    return _write(k, out)


def _encode_and_write(k: int, job: FrameJob, out: FrameOut):
    return _write(k, encode_device_frame(_SHARED[0], job, out))


def _encode_and_write_shared(k: int, job: FrameJob, out: FrameOut, layout: list):
    """``_encode_and_write`` of a frame whose arrays wait in the shared ring (read in place: the
    slot stays this frame's until it commits, and nothing returned keeps a view of it)."""
    a = _RING.get(layout)
    out = replace(out, rgb8=a["rgb8"], frame=replace(out.frame, semantic=a["semantic"], depth=a["depth"],
                                                      instance=a["instance"]))
    return _write(k, encode_device_frame(_SHARED[0], job, out))


def _write(k: int, out: FrameOut):
    """Frame ``k``'s files; returns (the frame's records, what commit needs, {phase: seconds}).
    Arrays commit does not need are dropped here (from a worker process they would travel back).
    Files that came encoded (``out.encoded``: ``gpu_shards``) are only stored ("store" seconds;
    their encoding is the frame's "write"), or nothing when the task placed them already."""
    writer = _SHARED[1]
    t0 = time.perf_counter()
    if out.encoded is not None:
        if out.encoded.written.index != k:
            raise RoadtwinError(f"frame {k} came encoded as frame {out.encoded.written.index}")
        written = writer.write_encoded(out.encoded)
        return replace(out, encoded=None), written, {"store": time.perf_counter() - t0}
    written = writer.write(k, out.frame, out.rgb8, out.image_bytes, out.rgb8_right, out.image_bytes_right)
    t_write = time.perf_counter() - t0
    if len(written.states) == len(writer.writers):      # no writer left for commit: no arrays needed
        written = written.without_arrays()
    return replace(out, frame=None, rgb8=None, image_bytes=None, rgb8_right=None, image_bytes_right=None), \
        written, {"write": t_write}


def render_in_process(ctx: RenderContext, jobs: list[FrameJob], sink: FrameSink) -> None:
    """Every frame rendered here, in order (one device, one scene upload), each finished and
    written by the sink's pool while the next renders."""
    scene, t_prepare = prepared_scene(ctx)
    if finish_on_device(ctx, jobs, getattr(scene, "device", None)):
        for job, out in render_on_device(ctx, scene, jobs):
            sink.put_device(job, out)
    else:
        for job in jobs:
            sink.finish(job, render_views(ctx, scene, job), scene)
    sink.phases["prepare"] = sink.phases.get("prepare", 0.0) + t_prepare
