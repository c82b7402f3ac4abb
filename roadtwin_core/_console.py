"""The consoles every CLI command prints through: one place decides how output looks.

``soft_wrap``: messages that carry file paths are never broken across lines (tables still fit
the terminal width).
"""
from rich.console import Console

console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)
