"""Frames spread over the GPUs of a Ray cluster: one contiguous shard of frames a GPU.

Why: one process drives one device (``frame_sink.render_in_process``); a machine with several
GPUs, or several machines, render faster only if each card gets its own process with its own
scene upload. With ``--executor ray`` and a CUDA ``--device`` the frame jobs are cut into one
contiguous shard per GPU of the cluster (``ray.cluster_resources()["GPU"]``) and each shard runs
as one Ray generator task with ``num_gpus=1``: Ray sets the task's ``CUDA_VISIBLE_DEVICES`` to its
card, so the task renders on ``cuda:0``. A task does what the local GPU path does for its shard:
it forks its finishing processes first (its node's cores shared out over the node's GPUs, one
left for the task; forked before the scene goes to the card, as ``FrameSink`` does), then
prepares the scene once and renders its frames in order, finished on the device when the
renderer can (``device_frames``), else by ``pipeline.finish_frame`` in those processes. The
processes also encode the frame's files (``DatasetWriter.encode``: JPEG, label and instance
PNGs, COCO masks). Where the task shares the driver's filesystem (its processes read back a
token file the driver made in its staging folder, the output's temporary) they write the files
straight into that folder (``DatasetWriter.place``: the paths and hard links of ``write``), and
only the frames' records stream back (``num_returns="streaming"``, small batches); elsewhere
(a node without that folder) the files stream back as bytes and the driver stores them. The
driver commits in frame order (``FrameSink.put_at``); on error the staging folder goes whole,
as ever (``atomic_output_dir``), once the tasks are cancelled.
Python threads in the task or the driver would hold the GIL for that work (4x its seconds a
frame). Frame ``i`` depends only on ``(seed, i)``, so the bytes are those of the local executor
on the same kind of device. See docs/architecture.md (executors).

The task asks Ray for one CPU only (``num_cpus=1``), though its processes use its share of the
node's cores: Ray's CPUs are a scheduling count, and asking for a share would leave a task
unscheduled on a cluster whose nodes declare fewer CPUs than that, or differ from one another.
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import secrets
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

from ...errors import RoadtwinError
from .device_frames import encode_device_frame, finish_on_device, render_on_device
from .frame_sink import SceneDevice, travelling
from .pipeline import FrameJob, FrameOut, RenderContext, finish_frame, prepared_scene, render_views
from .writers import WRITERS, DatasetWriter

__all__ = ["on_gpus", "render_on_gpus", "split_shards"]

BATCH = 8                 # frames a streamed batch (a Ray object)
AHEAD = 4                 # batches a task may stream ahead of the driver (object store memory stays bounded)

_SHARD: dict | None = None          # what a task's finishing processes use (set before they fork)
_WRITER: DatasetWriter | None = None    # a finishing process's own writer, on its scratch folder


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
        n_gpus = int(ray.cluster_resources().get("GPU", 0))
        if n_gpus < 1:
            where = runner.address or "the local Ray cluster"
            raise RoadtwinError(f"--executor ray with --device {ctx.params.device}: {where} has no GPU "
                                f"(start its nodes with GPUs, or render with --device cpu)")
        shards = split_shards(len(jobs), n_gpus)
        task = ray.remote(max_calls=1)(_render_shard).options(   # a fresh worker a shard: its own CUDA context
            num_gpus=1, num_cpus=1, num_returns="streaming", _generator_backpressure_num_objects=AHEAD)
        spec = _writer_spec(sink.writer)
        with _offered_staging(sink.writer if spec else None) as staging:
            shared = ray.put({"ctx": _on_own_card(ctx), "writer": spec and {**spec, "staging": staging},
                              "processes": _processes_per_gpu(ray)})
            gens = {task.remote(shared, r.start, [_on_own_card(jobs[i]) for i in r]): s
                    for s, r in enumerate(shards)}
            try:
                sink.shards = _collect(ray, gens, shards, sink)
            finally:
                for gen in gens:
                    ray.cancel(gen, force=True)
                if gens:            # the staging folder is removed next: no task may write there then
                    with suppress(Exception):       # the error that brought us here is the one to tell
                        ray.wait([gen.completed() for gen in gens], num_returns=len(gens), timeout=30)


@contextmanager
def _offered_staging(writer) -> Iterator[dict | None]:
    """The writer's folder (the output's staging folder) offered to the tasks: its path and a
    token file made there, removed afterwards. A task whose processes read the token back
    shares this filesystem and writes the frames' files in place (``_staging_writer``)."""
    if writer is None:
        yield None
        return
    root = Path(writer.root).resolve()
    token = secrets.token_hex(16)
    path = root / f".roadtwin-shard-token-{token[:8]}"
    try:
        _write_token(path, token)
        yield {"root": str(root), "token_file": str(path), "token": token}
    finally:
        path.unlink(missing_ok=True)


def _write_token(path: Path, token: str) -> None:
    path.write_text(token)


def _processes_per_gpu(ray) -> dict[str, int]:
    """Node id -> finishing processes of a GPU task there: the node's CPUs shared out over its
    GPUs, one left for the task itself (at least one)."""
    out = {}
    for node in ray.nodes():
        res = node.get("Resources", {})
        if node.get("Alive") and res.get("GPU"):
            out[node["NodeID"]] = max(1, int(res.get("CPU", 1) // res["GPU"]) - 1)
    return out


def _writer_spec(writer) -> dict | None:
    """How the tasks' processes make the driver's dataset writer on a scratch folder, or None
    (they hand back arrays, the driver writes): only the core's formats are encoded there, so
    the driver's writers must begin with those (plugins' come after: they run at commit, on
    the frame's arrays)."""
    if not isinstance(writer, DatasetWriter):
        return None
    core = [cls for name, cls in WRITERS.items() if name in writer.formats]
    if [type(w) for w in writer.writers[:len(core)]] != core:
        return None
    return {"fields": writer.spec(), "keep_frame": len(writer.writers) > len(core)}


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
            if isinstance(value, dict):             # where the task runs (first), when it rendered (last)
                info[s] = {"streamed_bytes": 0, **info[s], **value}
                continue
            for out in value:
                if out.encoded is not None:
                    info[s]["streamed_bytes"] += sum(len(b) for b in out.encoded.files.values())
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


def _render_shard(shared: dict, first: int, jobs: list[FrameJob]) -> Iterator[Any]:
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
