"""The ``roadtwin`` command line: one module per command group, each parsing options and calling a
function a Python user can call too (``roadtwin_core.apps.*``). ``main`` turns bad input into one
line on stderr and exit code 2."""
from .main import app, main

__all__ = ["app", "main"]
