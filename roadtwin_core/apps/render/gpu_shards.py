"""Frames spread over the GPUs of a Ray cluster: one contiguous shard of frames a GPU.

Why: one process drives one device (``frame_sink.render_in_process``); a machine with several
GPUs, or several machines, render faster only if each card gets its own process with its own
scene upload. With ``--executor ray`` and a CUDA ``--device`` the frame jobs are cut into one
contiguous shard per GPU of the cluster (``ray.cluster_resources()["GPU"]``) and each shard runs
as one Ray generator task with ``num_gpus=1``: Ray sets the task's ``CUDA_VISIBLE_DEVICES`` to its
card, so the task renders on ``cuda:0``. A task does what the local GPU path does for its shard:
the scene prepared once, frames rendered in order and finished on the device when the renderer
can (``device_frames``), else ``pipeline.finish_frame``; the finishing and JPEG encoding run on
the task's threads. Finished frames stream back in small batches (``num_returns="streaming"``)
and the driver writes each as it arrives (``FrameSink.put_at``: files on threads, frames
committed in frame order). Frame ``i`` depends only on ``(seed, i)``, so the bytes are those of
the local executor on the same kind of device. See docs/architecture.md (executors).
"""
from __future__ import annotations

import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any, Iterator

from ...errors import RoadtwinError
from .device_frames import encode_device_frame, finish_on_device, render_on_device
from .pipeline import FrameJob, FrameOut, RenderContext, finish_frame, prepared_scene, render_views

__all__ = ["on_gpus", "render_on_gpus", "split_shards"]

BATCH = 8                 # frames a streamed batch (a Ray object)
AHEAD = 4                 # batches a task may stream ahead of the driver (object store memory stays bounded)


def on_gpus(device: str | None) -> bool:
    """Whether ``--device`` asks for GPUs (then Ray renders one shard a GPU). The driver's own
    default device says nothing about the cluster's, so only an explicit ``cuda...`` counts."""
    return str(device or "").startswith("cuda")


def split_shards(n_frames: int, n_gpus: int) -> list[range]:
    """``n_frames`` frame indices cut into at most ``n_gpus`` contiguous, near-equal ranges."""
    n = max(1, min(int(n_gpus), n_frames))
    bounds = [round(k * n_frames / n) for k in range(n + 1)]
    return [range(a, b) for a, b in zip(bounds, bounds[1:]) if b > a]


def render_on_gpus(runner, ctx: RenderContext, jobs: list[FrameJob], sink) -> None:
    """Every frame rendered by one Ray task a GPU and written through ``sink`` (``put_at``);
    ``sink.shards`` records what each task rendered, and where."""
    with runner.cluster() as ray:
        resources = ray.cluster_resources()
        n_gpus = int(resources.get("GPU", 0))
        if n_gpus < 1:
            where = runner.address or "the local Ray cluster"
            raise RoadtwinError(f"--executor ray with --device {ctx.params.device}: {where} has no GPU "
                                f"(start its nodes with GPUs, or render with --device cpu)")
        shards = split_shards(len(jobs), n_gpus)
        threads = max(1, int(resources.get("CPU", 1) // n_gpus))
        task = ray.remote(max_calls=1)(_render_shard).options(   # a fresh worker a shard: its own CUDA context
            num_gpus=1, num_cpus=1, num_returns="streaming", _generator_backpressure_num_objects=AHEAD)
        ctx_ref = ray.put(_on_own_card(ctx))
        gens = {task.remote(ctx_ref, [_on_own_card(jobs[i]) for i in r], threads): s for s, r in enumerate(shards)}
        try:
            sink.shards = _collect(ray, gens, shards, sink)
        finally:
            for gen in gens:
                ray.cancel(gen, force=True)


def _collect(ray, gens: dict, shards: list[range], sink) -> list[dict]:
    """Batches taken from whichever task has one ready, each frame handed to ``sink.put_at``."""
    nxt = [r.start for r in shards]
    info: list[dict] = [{} for _ in shards]
    while gens:
        ready, _ = ray.wait(list(gens), num_returns=1)
        for gen in ready:
            s = gens[gen]
            try:
                ref = next(gen)
            except StopIteration:
                del gens[gen]
                continue
            value = _get(ray, ref)
            if isinstance(value, dict):
                info[s] = value
                continue
            for out in value:
                sink.put_at(nxt[s], out)
                nxt[s] += 1
    for s, r in enumerate(shards):
        if nxt[s] != r.stop:
            raise RoadtwinError(f"GPU shard {s}: frames {nxt[s]}..{r.stop - 1} never came back")
    return [{"frames": len(r), "first": r.start, **info[s]} for s, r in enumerate(shards)]


def _get(ray, ref):
    """``ray.get``; a task's RoadtwinError comes back as itself (one line), not Ray's wrapper."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        if isinstance(exc.cause, RoadtwinError):
            raise exc.cause from None
        raise


def _on_own_card(item):
    """A context or job whose CUDA device is ``cuda:0``: inside a task the only card visible."""
    params = item.params
    if str(params.device or "").startswith("cuda") and params.device != "cuda:0":
        return replace(item, params=replace(params, device="cuda:0"))
    return item


def _render_shard(ctx: RenderContext, jobs: list[FrameJob], threads: int) -> Iterator[Any]:
    """The Ray task of one shard: first where it runs, then its finished frames in batches."""
    import ray

    yield {"gpu": os.environ.get("CUDA_VISIBLE_DEVICES"), "gpu_ids": [str(g) for g in ray.get_gpu_ids()],
           "node": ray.get_runtime_context().get_node_id()}
    batch: list[FrameOut] = []
    for out in _finished_frames(ctx, jobs, threads):
        batch.append(out)
        if len(batch) == BATCH:
            yield batch
            batch = []
    if batch:
        yield batch


def _finished_frames(ctx: RenderContext, jobs: list[FrameJob], threads: int) -> Iterator[FrameOut]:
    """What ``render_in_process`` does for the sink, here: frames rendered in order on this
    process's device, finished (and JPEG-encoded) on ``threads`` threads, in frame order."""
    scene, t_prepare = prepared_scene(ctx)
    with ThreadPoolExecutor(threads, thread_name_prefix="shard-finish") as pool:
        if finish_on_device(ctx, jobs, getattr(scene, "device", None)):
            work = (pool.submit(encode_device_frame, ctx, job, out) for job, out in render_on_device(ctx, scene, jobs))
        else:
            work = (pool.submit(finish_frame, ctx, scene, job, render_views(ctx, scene, job)) for job in jobs)
        for k, out in enumerate(_in_order(work, 2 * threads)):
            if k == 0:
                out.timings["prepare"] = t_prepare
            yield out


def _in_order(futures: Iterator, limit: int) -> Iterator:
    """The futures' results in order, at most ``limit`` in flight (the next is made meanwhile)."""
    pending: deque = deque()
    for fut in futures:
        pending.append(fut)
        while len(pending) > limit or (pending and pending[0].done()):
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()
