"""One spawned helper process for the composer's side jobs (textures, renderer warm-up, preview).

Why: on a 2-core machine the composer is single-threaded while it reads, places, writes and
validates, so one core idles for seconds. Jobs that need nothing but their arguments run there.
Spawned, not forked: a fresh interpreter inherits no threads (USD's, TBB's) and no held locks,
and it may import warp and compile kernels without touching the composer's process. Jobs run one
at a time, in the order they were submitted; ``submit`` never blocks (a queue's feeder thread
sends the arguments), so handing over the town's meshes does not wait for an earlier job.

What a helper prints (library warnings, native libraries' notices) is kept in a file, not shown
as it happens: the composer replays it after a run that succeeded, so bad input still ends in
exactly one line whatever a helper was doing; a helper that dies is reported with its last line.

Jobs and results travel over two plain pipes, not ``multiprocessing.Queue``: a queue's locks are
named POSIX semaphores kept by multiprocessing's resource tracker, and a helper stopped while it
starts (bad input found just after it was launched) could leave the tracker printing "leaked
semaphore" warnings after the one line of the error. Pipes hold nothing the tracker keeps.
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import queue
import signal
import sys
import tempfile
import threading
import traceback
import types
from typing import Any, Callable

from ...errors import RoadtwinError

__all__ = ["Sidecar"]


def _serve(jobs, results, log_path: str) -> None:
    # Ctrl-C reaches the whole process group: the composer handles it and stops this process,
    # which must not print a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    log = os.open(log_path, os.O_WRONLY | os.O_APPEND)
    os.dup2(log, 1)
    os.dup2(log, 2)
    os.close(log)
    with contextlib.suppress(OSError):        # the composer reads it through its own descriptor
        os.unlink(log_path)
    while True:
        try:
            item = jobs.recv()
        except EOFError:                      # the composer is gone
            return
        if item is None:
            return
        ticket, fn, args = item
        try:
            outcome = (ticket, True, fn(*args))
        except RoadtwinError as exc:
            outcome = (ticket, False, RoadtwinError(str(exc)))
        except BaseException as exc:                      # noqa: BLE001 - reported in the composer
            outcome = (ticket, False, RuntimeError(f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
        sys.stdout.flush()
        sys.stderr.flush()
        try:
            results.send(outcome)
        except (TypeError, AttributeError, pickle.PicklingError) as exc:   # a result that cannot travel
            results.send((ticket, False, RuntimeError(f"the job's result cannot be sent back: {exc}")))


def _feed(outbox: queue.SimpleQueue, jobs) -> None:
    """Sends the submitted jobs in order, so that ``submit`` never waits for the helper to read."""
    while (item := outbox.get()) is not _STOP:
        try:
            jobs.send(item)
        except OSError:                       # the helper is gone: result() reports it
            return


_STOP = object()


@contextlib.contextmanager
def _main_module_hidden():
    """multiprocessing's spawn runs the parent's ``__main__`` again in the child (its rule for
    pickled functions from the main script), so a user's script that calls ``compose()`` without an
    ``if __name__ == "__main__"`` guard would compose again in the helper, which then fails. The
    helper runs only roadtwin's own functions: the main module is hidden while it starts."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


class Sidecar:
    """``with Sidecar() as side: t = side.submit(fn, *args); ...; side.result(t)``.

    ``fn`` must be importable by name (module level). A job's exception is raised again by
    :meth:`result`; a helper that dies (killed, out of memory) is reported, never waited for."""

    def __init__(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        fd, self._log_path = tempfile.mkstemp(prefix="roadtwin-helper-", suffix=".log")
        self._log = os.fdopen(fd, "rb")
        jobs_in, self._jobs = ctx.Pipe(duplex=False)
        self._results, results_out = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_serve, args=(jobs_in, results_out, self._log_path), daemon=True,
                                 name="roadtwin-sidecar")
        with _main_module_hidden():
            self._proc.start()
        jobs_in.close()          # the helper holds its own ends: its death reads as end-of-file here
        results_out.close()
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()
        self._feeder = threading.Thread(target=_feed, args=(self._outbox, self._jobs), daemon=True,
                                        name="roadtwin-sidecar-feeder")
        self._feeder.start()
        self._next, self._done, self._closed = 0, {}, False

    def submit(self, fn: Callable, *args: Any) -> int:
        self._next += 1
        self._outbox.put((self._next, fn, args))
        return self._next

    def end_when_done(self) -> None:
        """The process ends after the jobs submitted so far, giving its memory back; their results
        stay readable."""
        self._outbox.put(None)

    def result(self, ticket: int) -> Any:
        while ticket not in self._done:
            if self._results.poll(0.05):
                try:
                    got, ok, value = self._results.recv()
                except EOFError:
                    self._proc.join(1.0)
                    self._raise_dead()
                self._done[got] = (ok, value)
            elif not self._proc.is_alive() and not self._results.poll(0):
                self._raise_dead()
        ok, value = self._done.pop(ticket)
        if not ok:
            raise value
        return value

    def _raise_dead(self):
        last = (self.output().strip().splitlines() or [""])[-1]
        raise RoadtwinError(f"the composer's helper process ended unexpectedly "
                            f"(exit code {self._proc.exitcode}){': ' + last if last else ''}") from None

    def output(self) -> str:
        """What the helper printed so far (stdout and stderr)."""
        if self._log.closed:
            return ""
        self._log.seek(0)
        return self._log.read().decode(errors="replace")

    def replay_output(self) -> None:
        """Show what the helper printed, on this process's stderr (after a run that succeeded)."""
        text = self.output()
        if text:
            sys.stderr.write(text if text.endswith("\n") else text + "\n")
            sys.stderr.flush()

    def close(self) -> None:
        """Stop the helper now, whatever it is doing (a compose that failed does not wait); once."""
        if self._closed:
            return
        self._closed = True
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join()
        self._outbox.put(_STOP)
        self._feeder.join()      # a send in progress ends with the helper's end of the pipe
        self._jobs.close()
        self._results.close()
        self._log.close()
        with contextlib.suppress(OSError):
            os.unlink(self._log_path)

    def __enter__(self) -> "Sidecar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
