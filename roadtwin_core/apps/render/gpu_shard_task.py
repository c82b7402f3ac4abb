"""The Ray task of one GPU shard (``gpu_shards`` cuts the frames and runs one of these a card).

Where it runs, Ray has set ``CUDA_VISIBLE_DEVICES`` to its card, so it renders on ``cuda:0``. It
forks its finishing processes first (forked before the scene goes to the card, as ``FrameSink``
does), then prepares the scene once and renders its frames in order, finished on the device when
the renderer can (``device_frames``), else by ``pipeline.finish_frame`` in those processes, which
also encode each frame's files through the dataset writer: in place in the driver's staging
folder where the task sees the driver's token file there, else as bytes from a scratch folder.
It yields where it runs first, then its finished frames in batches of ``BATCH``, then when its
card rendered them. See docs/architecture.md (executors).
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import shutil
import signal
import tempfile
import time
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager, suppress
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterator

from .device_frames import encode_device_frame, finish_on_device, render_on_device
from .frame_sink import SceneDevice, travelling
from .pipeline import FrameJob, FrameOut, RenderContext, finish_frame, prepared_scene, render_views
from .writers import DatasetWriter

__all__ = ["BATCH", "on_own_card", "render_shard"]

BATCH = 8                 # frames a streamed batch (a Ray object)

_SHARD: dict | None = None          # what a task's finishing processes use (set before they fork)
_WRITER: DatasetWriter | None = None    # a finishing process's own writer, on its scratch folder


def on_own_card(item):
    """A context or job whose CUDA device is ``cuda:0``: inside a task the only card visible."""
    params = item.params
    if str(params.device or "").startswith("cuda") and params.device != "cuda:0":
        return replace(item, params=replace(params, device="cuda:0"))
    return item


def render_shard(shared: dict, first: int, jobs: list[FrameJob]) -> Iterator[Any]:
    """The Ray task of one shard (frames ``first``...): first where it runs, then its finished
    frames in batches."""
    import ray

    node = ray.get_runtime_context().get_node_id()
    n = shared["processes"].get(node, 1)
    direct = _staging_writer(shared["writer"])
    yield {"gpu": os.environ.get("CUDA_VISIBLE_DEVICES"), "gpu_ids": [str(g) for g in ray.get_gpu_ids()],
           "node": node, "processes": n, "direct": direct is not None}
    batch: list[FrameOut] = []
    started = None
    with _finishing_pool(shared, n, direct) as pool:        # forked before the scene goes to the card
        for out in _finished_frames(shared["ctx"], first, jobs, pool, n):
            started = started or time.time()
            batch.append(out)
            if len(batch) == BATCH:
                yield batch
                batch = []
    if batch:
        yield batch
    # when this card rendered (wall clock: shards of one host overlap when they ran at once) and which card it was
    yield {"frames_from_to": [round(started or time.time(), 3), round(time.time(), 3)],
           "card": _card(shared["ctx"])}


def _card(ctx: RenderContext) -> str | None:
    """The PCI bus id of the task's CUDA device (which physical card ``cuda:0`` was), or None."""
    if not str(ctx.params.device or "").startswith("cuda"):
        return None
    with suppress(Exception):
        import warp as wp

        return str(getattr(wp.get_device("cuda:0"), "pci_bus_id", None))
    return None


def _staging_writer(spec: dict | None) -> DatasetWriter | None:
    """A writer on the driver's staging folder where this task sees the token the driver made
    there (one filesystem; forked processes see what their task sees), else None (the files
    travel as bytes)."""
    staging = (spec or {}).get("staging")
    if not staging:
        return None
    try:
        seen = Path(staging["token_file"]).read_text() == staging["token"]
    except OSError:
        return None
    return DatasetWriter(root=Path(staging["root"]), **spec["fields"]) if seen else None


@contextmanager
def _finishing_pool(shared: dict, n: int, direct: DatasetWriter | None) -> Iterator[ProcessPoolExecutor]:
    """``n`` forked processes that finish and encode frames: into ``direct``'s folder (the
    driver's staging folder), else each on its own scratch folder (in memory where ``/dev/shm``
    is; made only then), removed afterwards."""
    global _SHARD
    scratch = None
    if shared["writer"] is not None and direct is None:
        scratch = Path(tempfile.mkdtemp(prefix="roadtwin-shard-", dir="/dev/shm" if os.access("/dev/shm", os.W_OK)
                                        else None))
    _SHARD = {"ctx": shared["ctx"], "writer": shared["writer"], "scratch": scratch, "direct": direct}
    pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"), initializer=_end_with_parent)
    try:
        pool.submit(int).result()         # fork every process now, before the device is touched
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
        _SHARD = None


def _end_with_parent() -> None:
    """A finishing process ends with its task's process (a cancelled task's worker is killed;
    its pool's processes would wait on their queue for ever). Linux only; elsewhere a no-op."""
    with suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(1, int(signal.SIGKILL))     # PR_SET_PDEATHSIG


def _finished_frames(ctx: RenderContext, first: int, jobs: list[FrameJob], pool: ProcessPoolExecutor,
                     n: int) -> Iterator[FrameOut]:
    """What ``render_in_process`` does for the sink, here: frames rendered in order on this
    process's device, finished and encoded by ``pool``'s ``n`` processes, in frame order."""
    scene, t_prepare = prepared_scene(ctx)
    if finish_on_device(ctx, jobs, getattr(scene, "device", None)):
        work = (pool.submit(_encode_device, first + j, job, out)
                for j, (job, out) in enumerate(render_on_device(ctx, scene, jobs)))
    else:
        dev = SceneDevice(getattr(scene, "backend", None), getattr(scene, "device", None))
        work = (pool.submit(_finish, first + j, job, travelling(ctx, render_views(ctx, scene, job)), dev)
                for j, job in enumerate(jobs))
    for k, out in enumerate(_in_order(work, 2 * n)):
        if k == 0:
            out.timings["prepare"] = t_prepare
        yield out


def _encode_device(k: int, job: FrameJob, out: FrameOut) -> FrameOut:
    """In a finishing process: a device-finished frame ``k`` encoded (``encode_device_frame``), its files as bytes."""
    return _encoded(k, encode_device_frame(_SHARD["ctx"], job, out))


def _finish(k: int, job: FrameJob, rendered: tuple, dev: SceneDevice) -> FrameOut:
    """In a finishing process: frame ``k`` finished on the CPU (``finish_frame``), its files as bytes."""
    return _encoded(k, finish_frame(_SHARD["ctx"], dev, job, rendered))


def _encoded(k: int, out: FrameOut) -> FrameOut:
    """Frame ``k``'s files written in the driver's staging folder (``placed``) or encoded as
    bytes by this process's scratch writer (``out.encoded``), its arrays dropped; unchanged
    when the driver's writer cannot take them."""
    global _WRITER
    spec = _SHARD["writer"]
    if spec is None:
        return out
    if _SHARD["direct"] is None and _WRITER is None:
        _WRITER = DatasetWriter(root=_SHARD["scratch"] / f"p{os.getpid()}", **spec["fields"])
    t0 = time.perf_counter()
    how = _WRITER.encode if _SHARD["direct"] is None else _SHARD["direct"].place
    encoded = how(k, out.frame, out.rgb8, out.image_bytes, out.rgb8_right, out.image_bytes_right,
                  keep_frame=spec["keep_frame"])
    out.timings["write"] = time.perf_counter() - t0
    return replace(out, frame=None, rgb8=None, image_bytes=None, rgb8_right=None, image_bytes_right=None,
                   encoded=encoded)


def _in_order(futures: Iterator, limit: int) -> Iterator:
    """The futures' results in order, at most ``limit`` in flight (the next is made meanwhile)."""
    pending: deque = deque()
    for fut in futures:
        pending.append(fut)
        while len(pending) > limit or (pending and pending[0].done()):
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()
