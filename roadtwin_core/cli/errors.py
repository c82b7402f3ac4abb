"""How the command line reports a failure: one line on stderr, then an exit code."""
from __future__ import annotations

import typer
from rich.markup import escape

from .._console import err_console

__all__ = ["fail"]


def fail(message: str, code: int = 2) -> None:
    """Print ``error: MESSAGE`` and exit with ``code`` (2: the user's input was wrong)."""
    # The message is plain text: a path or value with [brackets] must not be read as markup.
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)
