"""The ``roadtwin`` command line (typer + rich): the commands of each group assembled into one app,
and every failure mapped to an exit code. Bad input: one line on stderr, exit code 2."""
from __future__ import annotations

import os
import sys

import typer

from ..errors import RoadtwinError
from .compose import compose
from .drive import drive
from .errors import fail
from .library import library_app
from .plan import plan
from .plugins import plugins
from .reconstruct import reconstruct_app
from .render import render, rig_app
from .stage import export, import_command, validate
from .sweep import sweep

__all__ = ["app", "main"]

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="roadtwin: simulation-ready digital twins of roads with their defects, as OpenUSD.")
app.command("plugins")(plugins)
app.command("compose")(compose)
app.command("validate")(validate)
app.command("export")(export)
app.command("import")(import_command)
app.command("render")(render)
app.add_typer(rig_app, name="rig")
app.command("plan")(plan)
app.command("sweep")(sweep)
app.command("drive")(drive)
app.add_typer(library_app, name="library")
app.add_typer(reconstruct_app, name="reconstruct")


def main() -> None:
    """``roadtwin``: run the app; a RoadtwinError or a usage error is one line and exit code 2, an
    unexpected exception one line and exit code 1 (``ROADTWIN_DEBUG=1``: its traceback)."""
    try:
        rc = app(standalone_mode=False)
        if isinstance(rc, int) and rc:
            sys.exit(rc)
    except RoadtwinError as exc:
        _safe_fail(str(exc))
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        _safe_fail("aborted", 130)
    except Exception as exc:  # click usage errors and the like
        if _is_click_error(exc):
            # a usage error is the user's mistake: one line naming the option, exit 2
            message = " ".join(exc.format_message().split())
            _safe_fail(f"{message} (see roadtwin --help)", 2)
        if os.environ.get("ROADTWIN_DEBUG"):
            raise
        _safe_fail(f"internal error: {type(exc).__name__}: {exc} (set ROADTWIN_DEBUG=1 for a traceback)", 1)


def _is_click_error(exc: Exception) -> bool:
    """click's own exceptions; typer >= 0.16 ships a private copy of click, so match by class
    name along the MRO rather than by ``isinstance(exc, click.ClickException)``."""
    return any(c.__name__ == "ClickException" for c in type(exc).__mro__) and hasattr(exc, "format_message")


def _safe_fail(message: str, code: int = 2) -> None:
    try:
        fail(message, code)
    except typer.Exit:
        sys.exit(code)


if __name__ == "__main__":
    main()
