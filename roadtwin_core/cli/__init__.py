"""The ``roadtwin`` command line: one module per command group, each parsing options and calling
a function a Python user can call too (``roadtwin_core.apps.*``). ``main`` turns bad input into
one line on stderr and exit code 2.

A command imports its app inside the command function, when it runs: the apps load USD and scipy,
and ``roadtwin --help`` (which imports every command module) must not wait for them
(docs/architecture.md, "Light entry points stay light").
"""
from .main import app, main

__all__ = ["app", "main"]
