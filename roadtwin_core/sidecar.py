"""One spawned helper process for the composer's side jobs (textures, renderer warm-up, preview).

Why: on a 2-core machine the composer is single-threaded while it reads, places, writes and
validates, so one core idles for seconds. Jobs that need nothing but their arguments run there.
Spawned, not forked: a fresh interpreter inherits no threads (USD's, TBB's) and no held locks,
and it may import warp and compile kernels without touching the composer's process. Jobs run one
at a time, in the order they were submitted; ``submit`` never blocks (a queue's feeder thread
sends the arguments), so handing over the town's meshes does not wait for an earlier job.
"""
from __future__ import annotations

import multiprocessing
import queue
import signal
import traceback
from typing import Any, Callable

from .errors import RoadtwinError

__all__ = ["Sidecar"]


def _serve(jobs, results) -> None:
    # Ctrl-C reaches the whole process group: the composer handles it and stops this process,
    # which must not print a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        item = jobs.get()
        if item is None:
            return
        ticket, fn, args = item
        try:
            results.put((ticket, True, fn(*args)))
        except RoadtwinError as exc:
            results.put((ticket, False, RoadtwinError(str(exc))))
        except BaseException as exc:                      # noqa: BLE001 - reported in the composer
            results.put((ticket, False, RuntimeError(f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}")))


class Sidecar:
    """``with Sidecar() as side: t = side.submit(fn, *args); ...; side.result(t)``.

    ``fn`` must be importable by name (module level). A job's exception is raised again by
    :meth:`result`; a helper that dies (killed, out of memory) is reported, never waited for."""

    def __init__(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._jobs, self._results = ctx.Queue(), ctx.Queue()
        self._proc = ctx.Process(target=_serve, args=(self._jobs, self._results), daemon=True,
                                 name="roadtwin-sidecar")
        self._proc.start()
        self._next, self._done, self._closed = 0, {}, False

    def submit(self, fn: Callable, *args: Any) -> int:
        self._next += 1
        self._jobs.put((self._next, fn, args))
        return self._next

    def end_when_done(self) -> None:
        """The process ends after the jobs submitted so far, giving its memory back; their results
        stay readable."""
        self._jobs.put(None)

    def result(self, ticket: int) -> Any:
        while ticket not in self._done:
            try:
                got, ok, value = self._results.get(timeout=0.05)
                self._done[got] = (ok, value)
            except queue.Empty:
                if self._proc.is_alive():
                    continue
                try:                     # it flushed its results before it ended: read what is left
                    got, ok, value = self._results.get(timeout=1.0)
                    self._done[got] = (ok, value)
                except queue.Empty:
                    raise RoadtwinError(f"the composer's helper process ended unexpectedly "
                                        f"(exit code {self._proc.exitcode})") from None
        ok, value = self._done.pop(ticket)
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Stop the helper now, whatever it is doing (a compose that failed does not wait); once."""
        if self._closed:
            return
        self._closed = True
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join()
        for q in (self._jobs, self._results):
            q.cancel_join_thread()
            q.close()

    def __enter__(self) -> "Sidecar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
