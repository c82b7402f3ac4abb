"""Where per-segment work runs: in-process, a local process pool, or a Ray cluster.

Every executor maps a pure function over items and returns results *in item order*, so the
output bytes do not depend on the executor or on scheduling. ``imap`` yields them in item order
as they arrive, so a consumer (a dataset writer) keeps only what it has not written yet, not
every result of a 100,000-frame render. Large shared inputs (the surface
model, the merger, the rules) travel once per worker as a *context*, not once per task:
forked workers inherit it, Ray workers get it through the object store.
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Iterator, Sequence

from .errors import RoadtwinError

Task = Callable[[Any, Any], Any]  # fn(context, item) -> result
Progress = Callable[[int, int], None]

_CONTEXT: Any = None


def _run_with_global_context(fn: Task, index: int, item: Any) -> tuple[int, Any]:
    return index, fn(_CONTEXT, item)


class SerialExecutor:
    name = "serial"

    def map(self, fn: Task, context: Any, items: Sequence[Any], progress: Progress | None = None) -> list[Any]:
        return list(self.imap(fn, context, items, progress))

    def imap(self, fn: Task, context: Any, items: Sequence[Any], progress: Progress | None = None) -> Iterator[Any]:
        for k, item in enumerate(items):
            result = fn(context, item)
            if progress:
                progress(k + 1, len(items))
            yield result


class LocalExecutor:
    """A fork-based process pool (the default on Linux); falls back to serial for tiny jobs."""

    name = "local"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = workers or os.cpu_count() or 1

    def map(self, fn: Task, context: Any, items: Sequence[Any], progress: Progress | None = None) -> list[Any]:
        if self.workers <= 1 or len(items) <= 1:
            return SerialExecutor().map(fn, context, items, progress)
        global _CONTEXT
        _CONTEXT = context
        results: list[Any] = [None] * len(items)
        try:
            ctx = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(self.workers, mp_context=ctx) as pool:
                futures = [pool.submit(_run_with_global_context, fn, k, item) for k, item in enumerate(items)]
                for done, fut in enumerate(as_completed(futures), 1):
                    k, value = fut.result()
                    results[k] = value
                    if progress:
                        progress(done, len(items))
        finally:
            _CONTEXT = None
        return results

    def imap(self, fn: Task, context: Any, items: Sequence[Any], progress: Progress | None = None) -> Iterator[Any]:
        """Results in item order, each as soon as it and every earlier one are done."""
        if self.workers <= 1 or len(items) <= 1:
            yield from SerialExecutor().imap(fn, context, items, progress)
            return
        global _CONTEXT
        _CONTEXT = context
        try:
            ctx = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(min(self.workers, len(items)), mp_context=ctx) as pool:
                futures = [pool.submit(_run_with_global_context, fn, k, item) for k, item in enumerate(items)]
                for k, fut in enumerate(futures):
                    try:
                        _, value = fut.result()
                    except BaseException:
                        for f in futures[k:]:
                            f.cancel()
                        raise
                    futures[k] = None      # drop the result once handed over
                    if progress:
                        progress(k + 1, len(items))
                    yield value
        finally:
            _CONTEXT = None


class RayExecutor:
    """Ray tasks; connects to ``address`` or starts a local cluster when none is given."""

    name = "ray"

    def __init__(self, address: str | None = None, num_cpus: int | None = None) -> None:
        self.address = address
        self.num_cpus = num_cpus

    def imap(self, fn: Task, context: Any, items: Sequence[Any], progress: Progress | None = None) -> Iterator[Any]:
        """Results in item order (``ray.get`` of each task's reference in turn)."""
        with self.cluster() as ray:
            ctx_ref = ray.put(context)
            remote = ray.remote(_ray_task)
            refs = [remote.remote(fn, ctx_ref, item) for item in items]
            for k in range(len(refs)):
                value = ray.get(refs[k])
                refs[k] = None
                if progress:
                    progress(k + 1, len(items))
                yield value

    @contextlib.contextmanager
    def cluster(self) -> Iterator[Any]:
        """The ``ray`` module connected to the cluster (``address``, or a local one started here
        and shut down on leaving): what :meth:`imap` runs in, and work that schedules its own
        tasks (``apps/render/gpu_shards``)."""
        ray, started = self._connect()
        try:
            yield ray
        finally:
            if started:
                ray.shutdown()

    def _connect(self):
        try:
            import ray
        except ImportError:
            raise RoadtwinError("executor ray: the ray package is not installed (pip install ray)") from None
        started = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                      "logging_level": "ERROR"}
            if self.address:
                kwargs["address"] = self.address
            else:
                kwargs["num_cpus"] = self.num_cpus or os.cpu_count() or 1
            try:
                ray.init(**kwargs)
            except Exception as exc:
                raise RoadtwinError(f"executor ray: cannot reach cluster {self.address or 'local'}: {exc}") from None
            started = True
        return ray, started

    def map(self, fn: Task, context: Any, items: Sequence[Any], progress: Progress | None = None) -> list[Any]:
        ray, started = self._connect()
        try:
            ctx_ref = ray.put(context)
            remote = ray.remote(_ray_task)
            refs = [remote.remote(fn, ctx_ref, item) for item in items]
            index = {ref: k for k, ref in enumerate(refs)}
            results: list[Any] = [None] * len(items)
            pending = list(refs)
            done = 0
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    results[index[ref]] = ray.get(ref)
                    done += 1
                    if progress:
                        progress(done, len(items))
            return results
        finally:
            if started:
                ray.shutdown()


def _ray_task(fn: Task, context: Any, item: Any) -> Any:
    return fn(context, item)


def make_executor(name: str, address: str | None = None, workers: int | None = None):
    if name == "serial":
        return SerialExecutor()
    if name == "local":
        return LocalExecutor(workers)
    if name == "ray":
        return RayExecutor(address, workers)
    raise RoadtwinError(f"unknown executor {name!r} (known: local, serial, ray)")
