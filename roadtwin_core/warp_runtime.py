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

__all__ = ["CUDA_DRIVER_NOTICE", "start_warp", "without_cuda_driver_notice"]

CUDA_DRIVER_NOTICE = "Could not find or load the NVIDIA CUDA driver"


@contextlib.contextmanager
def without_cuda_driver_notice():
    """Drop warp's "no CUDA driver" notice, pass on everything else written to stderr meanwhile."""
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
            kept = [line for line in caught.read().decode(errors="replace").splitlines(keepends=True)
                    if CUDA_DRIVER_NOTICE not in line]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


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
