"""Plugins use only the public API.

The public API is ``roadtwin_core``'s ``__all__`` plus the ``__all__`` of the public modules below
(README, "Layout"). A plugin that reaches into anything else breaks when the core is refactored.
Imports are read from the source with ``ast`` (what a reviewer would grep for), and names are
resolved by importing the public modules. How modules may import each other (no cycle, which
imports may sit inside a function, the layers) is tests/core/test_imports.py.
"""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PUBLIC_MODULES = {"roadtwin_core", "roadtwin_core.geometry", "roadtwin_core.remesh", "roadtwin_core.atomic",
                  "roadtwin_core.planning", "roadtwin_core.vehicle", "roadtwin_core.render", "roadtwin_core.usd",
                  "roadtwin_core.warp_runtime"}

# Known violations, each (plugin file, module, name): none left. Should one ever be needed, the
# list only shrinks: an entry that is no longer a violation fails test_allowlist_is_current.
KNOWN_VIOLATIONS: set[tuple[str, str, str]] = set()


def core_imports_of(path: Path) -> list[tuple[str, str]]:
    """(module, name) for each ``roadtwin_core`` import anywhere in a plugin file (function-local
    ones too: they are API use all the same); ``import roadtwin_core.x`` gives (module, '')."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split(".")[0] == "roadtwin_core":
            out += [(node.module, a.name) for a in node.names]
        elif isinstance(node, ast.Import):
            out += [(a.name, "") for a in node.names if a.name.split(".")[0] == "roadtwin_core"]
    return out


def violations() -> set[tuple[str, str, str]]:
    found = set()
    for path in sorted((REPO / "plugins").rglob("*.py")):
        rel = path.relative_to(REPO).as_posix()
        for module, name in core_imports_of(path):
            if module not in PUBLIC_MODULES:
                found.add((rel, module, name))
            elif name and name != "*" and name not in importlib.import_module(module).__dict__.get("__all__", ()) \
                    and f"{module}.{name}" not in PUBLIC_MODULES:
                found.add((rel, module, name))
    return found


def test_public_modules_define_all_and_export_what_they_list():
    for module in sorted(PUBLIC_MODULES):
        mod = importlib.import_module(module)
        assert isinstance(getattr(mod, "__all__", None), list), f"{module} defines no __all__"
        missing = [n for n in mod.__all__ if not hasattr(mod, n)]
        assert not missing, f"{module}.__all__ lists names it does not define: {missing}"


def test_plugins_import_only_the_public_api():
    new = sorted(violations() - KNOWN_VIOLATIONS)
    assert not new, "plugins import private core names (use a public module's __all__):\n" + \
        "\n".join(f"  {f}: from {m} import {n}" for f, m, n in new)


def test_allowlist_is_current():
    """Fixed violations leave the list (so it only shrinks)."""
    stale = sorted(KNOWN_VIOLATIONS - violations())
    assert not stale, "no longer violations, remove from KNOWN_VIOLATIONS:\n" + "\n".join(map(str, stale))


def test_the_checker_sees_private_imports(tmp_path):
    """The parser finds module-level, function-local, dotted and plain imports alike."""
    f = tmp_path / "p.py"
    f.write_text("import numpy\nfrom roadtwin_core import field\nimport roadtwin_core.planning.grid\n"
                 "def g():\n    from roadtwin_core.usd.stage import read_mesh\n    from . import x\n")
    assert sorted(core_imports_of(f)) == [("roadtwin_core", "field"), ("roadtwin_core.planning.grid", ""),
                                          ("roadtwin_core.usd.stage", "read_mesh")]
