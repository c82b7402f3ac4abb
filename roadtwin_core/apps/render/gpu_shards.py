"""Frames spread over the GPUs of a Ray cluster: one contiguous shard of frames a GPU.

Why: one process drives one device (``frame_sink.render_in_process``); a machine with several
GPUs, or several machines, render faster only if each card gets its own process with its own
scene upload. With ``--executor ray`` and a CUDA ``--device`` the frame jobs are cut into one
contiguous shard per GPU of the cluster (``ray.cluster_resources()["GPU"]``) and each shard runs
as one Ray generator task with ``num_gpus=1``: Ray sets the task's ``CUDA_VISIBLE_DEVICES`` to its
card, so the task renders on ``cuda:0``. A task (``gpu_shard_task``) does what the local GPU
path does for its shard, with its finishing processes (its node's cores shared out over the
node's GPUs, one left for the task), which also encode the frame's files
(``DatasetWriter.encode``: JPEG, label and instance PNGs, COCO masks). Where the task shares the driver's filesystem (its processes read back a
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

import secrets
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Iterator

from ...errors import RoadtwinError
from .gpu_shard_task import on_own_card, render_shard
from .pipeline import FrameJob, RenderContext
from .writers import WRITERS, DatasetWriter

__all__ = ["on_gpus", "render_on_gpus", "split_shards"]

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
        n_gpus = int(ray.cluster_resources().get("GPU", 0))
        if n_gpus < 1:
            where = runner.address or "the local Ray cluster"
            raise RoadtwinError(f"--executor ray with --device {ctx.params.device}: {where} has no GPU "
                                f"(start its nodes with GPUs, or render with --device cpu)")
        shards = split_shards(len(jobs), n_gpus)
        task = ray.remote(max_calls=1)(render_shard).options(   # a fresh worker a shard: its own CUDA context
            num_gpus=1, num_cpus=1, num_returns="streaming", _generator_backpressure_num_objects=AHEAD)
        spec = _writer_spec(sink.writer)
        with _offered_staging(sink.writer if spec else None) as staging:
            shared = ray.put({"ctx": on_own_card(ctx), "writer": spec and {**spec, "staging": staging},
                              "processes": _processes_per_gpu(ray)})
            gens = {task.remote(shared, r.start, [on_own_card(jobs[i]) for i in r]): s
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
