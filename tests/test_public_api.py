"""Plugins use only the public API, and the core has no import cycle.

The public API is ``roadtwin_core``'s ``__all__`` plus the ``__all__`` of the public modules below
(README, "Layout"). A plugin that reaches into anything else breaks when the core is refactored;
an import cycle makes a module's behaviour depend on which one was imported first. Both are read
from the source with ``ast`` (what a reviewer would grep for), and names are resolved by
importing the public modules.
"""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CORE = REPO / "roadtwin_core"
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


# --------------------------------------------------------------------------- import cycles
def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _resolve(importer: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = importer.split(".")
    base = base if is_package else base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _top_level_imports(tree: ast.Module):
    """Import statements executed when the module is imported: not inside a function, a class
    method or an ``if TYPE_CHECKING:`` block."""
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            todo += node.orelse
        elif isinstance(node, (ast.If, ast.Try, ast.With)):
            todo += node.body + getattr(node, "orelse", []) + getattr(node, "finalbody", []) + \
                [s for h in getattr(node, "handlers", []) for s in h.body]
        elif isinstance(node, ast.ClassDef):
            todo += [s for s in node.body if not isinstance(s, (ast.FunctionDef, ast.AsyncFunctionDef))]


def import_graph(root: Path = CORE) -> dict[str, set[str]]:
    files = {module_name(p): p for p in root.rglob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in files}
    for mod, path in files.items():
        is_package = path.name == "__init__.py"
        for node in _top_level_imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:  # `from P import x`: the submodule P.x if there is one, else P itself
                base = _resolve(mod, is_package, node)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
            for t in targets:
                # importing a.b.c runs a/__init__ and a/b/__init__ first, except the packages the
                # importer is itself inside (already being imported: parent first)
                parts = t.split(".")
                for k in range(1, len(parts) + 1):
                    anc = ".".join(parts[:k])
                    if anc in files and anc != mod and not mod.startswith(anc + "."):
                        graph[mod].add(anc)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle (as a module list) or None; a package importing its own submodules is no cycle
    by itself, only when a submodule (transitively) imports something that imports the package."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state and (c := visit(n)):
                return c
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (c := visit(m)):
            return c
    return None


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_graph_reads_relative_and_lazy_imports(tmp_path):
    pkg = tmp_path / "roadtwin_core"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .a import f\n")
    (pkg / "a.py").write_text("from .sub import b\nimport typing\nif typing.TYPE_CHECKING:\n    from . import c\n"
                              "def f():\n    from . import c\n")
    (pkg / "c.py").write_text("from roadtwin_core.a import f\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "b.py").write_text("from ..c import f\n")
    global REPO
    old, REPO = REPO, tmp_path
    try:
        g = import_graph(pkg)
    finally:
        REPO = old
    assert g["roadtwin_core"] == {"roadtwin_core.a"}
    assert g["roadtwin_core.a"] == {"roadtwin_core.sub", "roadtwin_core.sub.b"}
    assert g["roadtwin_core.sub.b"] == {"roadtwin_core.c"}
    assert find_cycle(g) == ["roadtwin_core.a", "roadtwin_core.sub.b", "roadtwin_core.c", "roadtwin_core.a"]


def test_core_has_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle in roadtwin_core: " + " -> ".join(cycle)


def _absolute_imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
        elif isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
    return out


def test_core_imports_no_plugin_and_no_plugin_imports_another():
    plugins = {p.name for p in (REPO / "plugins").iterdir() if (p / "__init__.py").exists()}
    assert {"roadtwin_defects", "roadtwin_cdt"} <= plugins
    for path in CORE.rglob("*.py"):
        assert not _absolute_imports(path) & plugins, f"{path.relative_to(REPO)} imports a plugin"
    for path in (REPO / "plugins").rglob("*.py"):
        own = path.relative_to(REPO / "plugins").parts[0]
        others = _absolute_imports(path) & (plugins - {own})
        assert not others, f"{path.relative_to(REPO)} imports another plugin: {sorted(others)}"
