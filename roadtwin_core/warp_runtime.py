"""Starting warp the way every roadtwin command wants it: quiet.

warp's native library prints "Could not find or load the NVIDIA CUDA driver" (a C ``fprintf`` on
file descriptor 2, out of reach of ``warp.config``) when it starts on a machine without an NVIDIA
driver, i.e. on every CPU-only machine, where rendering and sweeps run on the CPU by design. And
its Python side logs a banner and one line per loaded module. Plugins that use warp start it
through :func:`start_warp`; warp itself is imported only then.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from typing import Callable

__all__ = ["CUDA_DRIVER_NOTICE", "filtered_stderr", "start_warp", "warp_device", "without_cuda_driver_notice"]

CUDA_DRIVER_NOTICE = "Could not find or load the NVIDIA CUDA driver"


@contextlib.contextmanager
def filtered_stderr(keep: Callable[[str], bool]):
    """What is written to file descriptor 2 meanwhile (native libraries included) is held back,
    then passed on line by line where ``keep(line)``; ``keep`` is asked after the block ran."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            kept = [line for line in caught.read().decode(errors="replace").splitlines(keepends=True) if keep(line)]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


def without_cuda_driver_notice():
    """Drop warp's "no CUDA driver" notice, pass on everything else written to stderr meanwhile."""
    return filtered_stderr(lambda line: CUDA_DRIVER_NOTICE not in line)


def warp_device(name: str | None = None):
    """``warp.get_device(name)``. A device this machine lacks raises warp's own exception, whose
    message says why; the native "Warp CUDA error ..." lines warp prints while it looks are
    dropped then, so a command can report it in one line."""
    wp = start_warp()
    failed = []
    with filtered_stderr(lambda line: not (failed and line.startswith("Warp CUDA error"))):
        try:
            return wp.get_device(name)
        except Exception as exc:
            failed.append(exc)
            raise


def start_warp():
    """``import warp``, initialised, with warnings only (no banner, no module-load lines) and
    without the no-CUDA-driver notice; returns the ``warp`` module. Cheap after the first call."""
    import warp as wp

    if hasattr(wp.config, "log_level") and hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    else:                                        # older warp
        wp.config.quiet = True
    if not getattr(start_warp, "_done", False):
        with without_cuda_driver_notice():
            wp.init()
        start_warp._done = True
    return wp
