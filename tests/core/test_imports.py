"""How roadtwin's modules import each other, read from the source with ``ast``.

- **No import cycle** among roadtwin's modules (the core and the plugins). Every import counts,
  also one inside a function: it runs the first time the function is called, and a cycle
  through it makes a module's behaviour depend on which one was imported first all the same.
- **An import inside a function defers a heavy or optional third-party package, nothing else.**
  The packages are :data:`LAZY_OPTIONAL` and :data:`LAZY_HEAVY_REQUIRED` (measured); any other
  import (roadtwin's own modules, the standard library, light packages) goes to the top of its
  module, where a reader sees what the module depends on. One rule covers the command line: a
  command imports its app inside the command function (:data:`CLI_LOADS_APPS_WHEN_RUN`). The few other
  roadtwin imports that must stay in a function are listed in :data:`LAZY_INTERNAL`, each with its
  reason; an entry that is no longer needed fails :func:`test_lazy_allowlists_are_current`, so the
  list only shrinks.
- **Layers**: the framework (``roadtwin_core`` outside ``apps/`` and ``cli/``) never imports an
  app or the command line, and nothing but the command line imports it; the core never imports
  a plugin, nor a plugin another.
- **Light entry points stay light**: the GPU-side packages (``roadtwin_core.vehicle``,
  ``roadtwin_core.render``), imported by the warp kernels on a machine with numpy and warp only,
  ``roadtwin_core.apps.render``, imported by Ray's render workers there, and the command line,
  whose ``--help`` must not wait for USD and scipy.

docs/architecture.md describes the layers.
"""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PLUGINS = REPO / "plugins"

# --------------------------------------------------------------------------- what may be deferred
#: Optional packages (pyproject's ``[all]`` extra, and Blender's ``bpy``): a module that imported
#: one at the top could not be imported without it, so an import inside a function may always
#: defer them. Import times after numpy (``python -X importtime``, 2-core machine, best of three):
#: torch 1.0 s, open3d 0.6 s, ray 0.3 s, rerun 0.3 s, warp 0.2 s (and it starts CUDA), pyarrow.parquet
#: 0.06 s, h5py 0.04 s, cv2 0.015 s, pybullet 0.001 s; rosbags (drive's ROS 2 bag writer) and mcap
#: (its reader, used by the tests only). :func:`test_optional_packages_are_the_extra` keeps this
#: equal to the extra.
LAZY_OPTIONAL = {"torch", "warp", "open3d", "ray", "cv2", "pybullet", "rerun", "h5py", "pyarrow", "rosbags", "mcap",
                 "bpy"}
#: Where the extra's distribution name is not the name imported.
_IMPORT_NAME = {"warp-lang": "warp", "opencv-python-headless": "cv2", "rerun-sdk": "rerun"}

#: Required packages (or subpackages) slow to import, for the one feature that needs them: an
#: import inside a function may defer them anywhere. The other required ones go to the top: pxr
#: (0.27-0.38 s) is needed by nearly every command; scipy.spatial / .ndimage / .sparse /
#: .spatial.transform (0.22-0.28 s, mostly a base they share) are loaded by the surfaces and the
#: plugins on every command that loads plugins; shapely 0.03 s, PIL 0.01 s, manifold3d, triangle,
#: platformdirs and pluggy under 0.01 s. scipy.signal (0.75 s) and scipy.interpolate (0.45 s) are
#: deferred on the GPU side only (:data:`GPU_SIDE`).
LAZY_HEAVY_REQUIRED: dict[str, str] = {
    "matplotlib": "0.22 s (pyplot: more), for the plots and colour maps only",
    "trimesh": "1.2 s, for the mesh exporter only",
    "scipy.optimize": "0.75 s alone, 0.2-0.3 s more than what loading the plugins brings, for stereo calibration only",
}

#: Packages whose modules may defer ANY third-party package but numpy: the warp kernels (physics,
#: renderer) import them on a GPU machine that has numpy and warp only, no USD nor scipy
#: (:func:`test_gpu_side_packages_stay_light` holds what they import at the top).
GPU_SIDE = ("roadtwin_core/vehicle/", "roadtwin_core/render/")

#: The command line's one rule: a module under ``roadtwin_core/cli/`` may import an app
#: (``roadtwin_core.apps.*``, nothing else) inside a command function. Each command loads its app
#: when it runs, so ``roadtwin --help``, which imports every command module, loads neither USD nor
#: scipy (:func:`test_the_command_line_loads_no_usd_scipy_or_plots`).
CLI_LOADS_APPS_WHEN_RUN = ("roadtwin_core/cli/", "roadtwin_core.apps")

#: The roadtwin imports that stay inside a function: (file, module imported) -> why. Short on
#: purpose; lift an import to the top of its module rather than add to this.
_GPU_NO_USD = "USD; roadtwin_core.render is imported on the GPU side, which has no USD (see GPU_SIDE)"
_GPU_NUMPY_ONLY = "roadtwin_core.vehicle is imported on the GPU side, with numpy and warp only (see GPU_SIDE)"
_NEEDS_WARP = "imports warp (optional) at the top: the plugin loads, and says what it needs, without it"
_RAY_RENDER_WORKER = ("Ray's render workers import roadtwin_core.apps.render (for pipeline.render_chunk) on the "
                      "GPU side, which has no USD nor scipy (see test_gpu_side_packages_stay_light)")
LAZY_INTERNAL: dict[tuple[str, str], str] = {
    ("roadtwin_core/apps/render/run.py", "roadtwin_core.usd.town_reader"): "USD; " + _RAY_RENDER_WORKER,
    ("roadtwin_core/apps/render/pipeline.py", "roadtwin_core.render.ego_lane"): "scipy; " + _RAY_RENDER_WORKER,
    ("roadtwin_core/apps/render/device_frames.py", "roadtwin_core.render.ego_lane"): "scipy; " + _RAY_RENDER_WORKER,
    ("roadtwin_core/looks/prefetch.py", "roadtwin_core.looks.cache"):
        "the texture generators (scipy.fft, ~0.1 s) load in the helper process that makes the set, not in the composer",
    ("roadtwin_core/render/rig_usd.py", "roadtwin_core.usd.town_reader"): _GPU_NO_USD,
    ("roadtwin_core/render/scene.py", "roadtwin_core.usd.looks_reader"): _GPU_NO_USD,
    ("roadtwin_core/render/scene_look.py", "roadtwin_core.usd.looks_reader"): _GPU_NO_USD,
    ("roadtwin_core/vehicle/roads.py", "roadtwin_core.surface"): "scipy and USD; " + _GPU_NUMPY_ONLY,
    ("roadtwin_core/vehicle/roads.py", "roadtwin_core.usd.town_reader"): "USD; " + _GPU_NUMPY_ONLY,
    ("roadtwin_core/vehicle/vehicle.py", "roadtwin_core.planning"):
        "planning loads scipy, USD and the plugin manager; " + _GPU_NUMPY_ONLY,
    ("plugins/roadtwin_pybullet/__init__.py", "roadtwin_pybullet.sim"):
        "imports pybullet (optional) at the top: the plugin loads, and says what it needs, without it",
    ("plugins/roadtwin_warp_physics/__init__.py", "roadtwin_warp_physics.kernels"): _NEEDS_WARP,
    ("plugins/roadtwin_warp_render/renderer.py", "roadtwin_warp_render.raycast"):
        _NEEDS_WARP + "; and warp must be started quietly (start_warp) before its kernels are defined",
    ("plugins/roadtwin_warp_render/renderer.py", "roadtwin_warp_render.event_kernels"): _NEEDS_WARP,
    ("plugins/roadtwin_warp_render/renderer.py", "roadtwin_warp_render.post"): _NEEDS_WARP,
    ("plugins/roadtwin_warp_render/renderer.py", "roadtwin_warp_render.exposure"): _NEEDS_WARP,
}


# --------------------------------------------------------------------------- reading imports
@dataclass(frozen=True)
class Import:
    """One imported name: ``module`` is what the statement imports, resolved to an absolute
    dotted name (a submodule when ``from P import x`` names one, else ``P.x`` for a third-party
    package, whose files are not read, and ``P`` for one of roadtwin's modules)."""

    path: str          # file, relative to the repository ("roadtwin_core/usd/stage.py")
    line: int
    module: str
    deferred: bool     # inside a function: runs when the function is called, not at import

    @property
    def top(self) -> str:
        return self.module.split(".")[0]

    def __str__(self) -> str:
        return f"{self.path}:{self.line} {self.module}"


def module_name(path: Path, root: Path) -> str:
    """The dotted name ``path`` is imported as, ``root`` being the folder on ``sys.path``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def source_files(repo: Path = REPO) -> dict[str, Path]:
    """Module name -> file for roadtwin's packages: ``roadtwin_core/`` and ``plugins/roadtwin_*/``."""
    files: dict[str, Path] = {}
    for top in (repo / "roadtwin_core", *sorted((repo / "plugins").glob("roadtwin_*"))):
        for path in sorted(top.rglob("*.py")):
            files[module_name(path, top.parent)] = path
    return files


def _is_type_checking(node: ast.If) -> bool:
    return "TYPE_CHECKING" in ast.unparse(node.test)


def imports_of(path: Path, module: str, known: set[str], repo: Path = REPO) -> list[Import]:
    """Every import statement of a file, module-level or inside a function (``if TYPE_CHECKING:``
    blocks never run and are skipped); ``known``: roadtwin's module names, to tell a submodule
    from a name in ``from P import x``."""
    is_package = path.name == "__init__.py"
    rel = path.relative_to(repo).as_posix()
    our_packages = {k.split(".")[0] for k in known}
    out: list[Import] = []

    def visit(node: ast.AST, deferred: bool) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child, deferred)
            return
        if isinstance(node, ast.Import):
            out.extend(Import(rel, node.lineno, a.name, deferred) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_package, node)
            ours = base.split(".")[0] in our_packages
            for a in node.names:
                sub = f"{base}.{a.name}"
                target = sub if (sub in known or not ours) and a.name != "*" else base
                out.append(Import(rel, node.lineno, target, deferred))
        inner = deferred or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        for child in ast.iter_child_nodes(node):
            visit(child, inner)

    visit(ast.parse(path.read_text(), str(path)), False)
    return out


def _resolve(importer: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = importer.split(".")
    base = base if is_package else base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def all_imports(repo: Path = REPO) -> dict[str, list[Import]]:
    """Module -> its imports, for every roadtwin module of the repository."""
    files = source_files(repo)
    return {m: imports_of(p, m, set(files), repo) for m, p in files.items()}


# --------------------------------------------------------------------------- import cycles
def import_graph(imports: dict[str, list[Import]]) -> dict[str, set[str]]:
    """Module -> the roadtwin modules it imports, at the top or in a function. Importing a.b.c
    runs a/__init__ and a/b/__init__ first, except the packages the importer is itself inside
    (already being imported: parent first)."""
    graph: dict[str, set[str]] = {m: set() for m in imports}
    for mod, found in imports.items():
        for imp in found:
            parts = imp.module.split(".")
            for k in range(1, len(parts) + 1):
                anc = ".".join(parts[:k])
                if anc in graph and anc != mod and not mod.startswith(anc + "."):
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


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per group of modules that import each other (strongly connected component), so
    every cycle is reported at once, not the first one found."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[set[str]] = []

    def visit(m: str) -> None:                     # Tarjan's algorithm
        index[m] = low[m] = len(index)
        stack.append(m)
        for n in sorted(graph[m]):
            if n not in index:
                visit(n)
                low[m] = min(low[m], low[n])
            elif n in stack:
                low[m] = min(low[m], index[n])
        if low[m] == index[m]:
            group = set()
            while True:
                n = stack.pop()
                group.add(n)
                if n == m:
                    break
            if len(group) > 1:
                groups.append(group)

    for m in sorted(graph):
        if m not in index:
            visit(m)
    return sorted(find_cycle({m: graph[m] & g for m in g}) for g in groups)


def _edge_lines(cycle: list[str], imports: dict[str, list[Import]]) -> list[str]:
    """Where each step of a cycle is imported (file:line module), so it can be cut."""
    lines = []
    for a, b in zip(cycle, cycle[1:]):
        where = [i for i in imports[a] if i.module == b or i.module.startswith(b + ".")]
        lines += [f"  {i}{'  (inside a function)' if i.deferred else ''}" for i in where[:1]]
    return lines


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None
    two = {"a": {"b"}, "b": {"a", "c"}, "c": {"d"}, "d": {"e"}, "e": {"c"}}
    assert import_cycles(two) == [["a", "b", "a"], ["c", "d", "e", "c"]]


def _tiny_repo(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def test_a_cycle_through_a_function_level_import_is_found(tmp_path):
    """The old usd/stage <-> usd/checks pair in small: each module imports the other only inside
    a function, so nothing fails at import time, and a checker reading only module-level imports
    saw no cycle."""
    repo = _tiny_repo(tmp_path, {
        "roadtwin_core/__init__.py": "",
        "roadtwin_core/usd/__init__.py": "",
        "roadtwin_core/usd/stage.py": "def read_mesh():\n    from .checks import check_points\n",
        "roadtwin_core/usd/checks.py": "def check_points():\n    pass\n\n\n"
                                       "def check_stage_meshes():\n    from .stage import read_mesh\n",
    })
    imports = all_imports(repo)
    assert import_cycles(import_graph(imports)) == [["roadtwin_core.usd.checks", "roadtwin_core.usd.stage",
                                                     "roadtwin_core.usd.checks"]]
    top_level_only = {m: [i for i in found if not i.deferred] for m, found in imports.items()}
    assert import_cycles(import_graph(top_level_only)) == []


def test_graph_reads_relative_lazy_and_plugin_imports(tmp_path):
    repo = _tiny_repo(tmp_path, {
        "roadtwin_core/__init__.py": "from .a import f\n",
        "roadtwin_core/a.py": "from .sub import b\nimport typing\nif typing.TYPE_CHECKING:\n    from . import c\n"
                              "def f():\n    from . import c\n",
        "roadtwin_core/c.py": "import numpy\nfrom roadtwin_core.a import f\n",
        "roadtwin_core/sub/__init__.py": "",
        "roadtwin_core/sub/b.py": "from ..c import f\nclass K:\n    from scipy import signal\n",
        "plugins/roadtwin_p/__init__.py": "from . import kern\n",
        "plugins/roadtwin_p/kern.py": "def g():\n    from roadtwin_core.sub import b\n    import warp as wp\n",
    })
    imports = all_imports(repo)
    g = import_graph(imports)
    assert g["roadtwin_core"] == {"roadtwin_core.a"}
    assert g["roadtwin_core.a"] == {"roadtwin_core.sub", "roadtwin_core.sub.b", "roadtwin_core.c"}
    assert g["roadtwin_core.sub.b"] == {"roadtwin_core.c"}
    assert g["roadtwin_p.kern"] == {"roadtwin_core", "roadtwin_core.sub", "roadtwin_core.sub.b"}
    assert find_cycle(g) == ["roadtwin_core.a", "roadtwin_core.c", "roadtwin_core.a"]
    assert [str(i) for i in imports["roadtwin_p.kern"]] == ["plugins/roadtwin_p/kern.py:2 roadtwin_core.sub.b",
                                                            "plugins/roadtwin_p/kern.py:3 warp"]
    assert all(i.deferred for i in imports["roadtwin_p.kern"])
    # a class body runs at import: not deferred; a third-party `from P import x` names P.x
    assert [(i.module, i.deferred) for i in imports["roadtwin_core.sub.b"]] == [("roadtwin_core.c", False),
                                                                               ("scipy.signal", False)]


def test_no_import_cycle():
    imports = all_imports()
    cycles = import_cycles(import_graph(imports))
    if cycles:
        pytest.fail("import cycles (imports inside functions count too):\n" + "\n".join(
            "  " + " -> ".join(c) + "\n" + "\n".join(_edge_lines(c, imports)) for c in cycles), pytrace=False)


# --------------------------------------------------------------------------- function-level imports
def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _third_party_reason(imp: Import) -> str | None:
    if imp.top in LAZY_OPTIONAL:
        return "optional"
    for package, why in LAZY_HEAVY_REQUIRED.items():
        if _within(imp.module, package):
            return why
    if imp.path.startswith(GPU_SIDE) and imp.top != "numpy":
        return "GPU side"
    return None


def _ours(imp: Import) -> bool:
    return imp.top == "roadtwin_core" or imp.top.startswith("roadtwin_")


def deferred_imports() -> list[Import]:
    return [i for found in all_imports().values() for i in found if i.deferred]


def _command_loads_its_app(imp: Import) -> bool:
    cli_folder, apps = CLI_LOADS_APPS_WHEN_RUN
    return imp.path.startswith(cli_folder) and _within(imp.module, apps)


def unexplained_deferred_imports(deferred: list[Import]) -> list[Import]:
    """Imports inside functions that neither :data:`LAZY_OPTIONAL`, :data:`LAZY_HEAVY_REQUIRED`,
    :data:`GPU_SIDE`, :data:`CLI_LOADS_APPS_WHEN_RUN` nor :data:`LAZY_INTERNAL` explains, once per
    file, line and module."""
    def explained(i: Import) -> bool:
        if not _ours(i):
            return _third_party_reason(i) is not None
        return _command_loads_its_app(i) or (i.path, i.module) in LAZY_INTERNAL

    return list(dict.fromkeys(i for i in deferred if not explained(i)))


def _by_line(found: list[Import]) -> list[str]:
    """``file:line module[, module...]``: one line per import statement."""
    lines: dict[tuple[str, int], list[str]] = {}
    for i in found:
        lines.setdefault((i.path, i.line), []).append(i.module)
    return [f"  {path}:{line} {', '.join(dict.fromkeys(mods))}" for (path, line), mods in lines.items()]


def test_imports_inside_functions_only_defer_heavy_optional_packages():
    bad = unexplained_deferred_imports(deferred_imports())
    ours = [i for i in bad if _ours(i)]
    others = [i for i in bad if not _ours(i)]
    message = []
    if ours:
        message += ["roadtwin modules imported inside a function: move the import to the top of the module "
                    "(or, where that truly cannot be, add it to LAZY_INTERNAL with the reason):", *_by_line(ours)]
    if others:
        message += ["standard-library or light packages imported inside a function: move the import to the top "
                    "of the module (heavy or optional packages: LAZY_OPTIONAL, LAZY_HEAVY_REQUIRED):",
                    *_by_line(others)]
    if bad:
        pytest.fail("\n".join(message), pytrace=False)


def test_lazy_allowlists_are_current():
    """An entry whose import has gone (lifted, or the code removed) leaves the list, so it only shrinks."""
    deferred = deferred_imports()
    present = {(i.path, i.module) for i in deferred}
    stale = sorted(set(LAZY_INTERNAL) - present)
    assert not stale, "no longer imported inside a function, remove from LAZY_INTERNAL:\n" + \
        "\n".join(f"  {f} {m}" for f, m in stale)
    unused = sorted(k for k in LAZY_HEAVY_REQUIRED if not any(_within(i.module, k) for i in deferred))
    assert not unused, f"no import inside a function defers these any more, remove from LAZY_HEAVY_REQUIRED: {unused}"


def test_optional_packages_are_the_extra():
    with open(REPO / "pyproject.toml", "rb") as f:
        extra = tomllib.load(f)["project"]["optional-dependencies"]["all"]
    names = {re.split(r"[<>=!~ \[]", req)[0] for req in extra}
    assert {_IMPORT_NAME.get(n, n) for n in names} | {"bpy"} == LAZY_OPTIONAL


def test_the_deferred_import_rule_reads_a_file(tmp_path):
    repo = _tiny_repo(tmp_path, {
        "roadtwin_core/__init__.py": "",
        "roadtwin_core/x.py": "import json\nfrom . import y\n\n\ndef f():\n    import torch\n    from . import y\n"
                              "    import re\n    from scipy import optimize\n    from scipy.spatial import cKDTree\n"
                              "    from pxr import Usd\n",
        "roadtwin_core/y.py": "",
        "roadtwin_core/render/__init__.py": "def f():\n    from pxr import Usd\n    import numpy\n",
        "roadtwin_core/apps/__init__.py": "",
        "roadtwin_core/apps/a.py": "def f():\n    from .. import y\n",
        "roadtwin_core/cli/__init__.py": "",
        "roadtwin_core/cli/a.py": "def run():\n    from ..apps.a import f\n    from .. import y\n",
    })
    imports = all_imports(repo)
    deferred = [i for found in imports.values() for i in found if i.deferred]
    assert [str(i) for i in unexplained_deferred_imports(deferred)] == [
        "roadtwin_core/apps/a.py:2 roadtwin_core.y",  # an app is no command: it imports at the top
        "roadtwin_core/cli/a.py:3 roadtwin_core.y",   # a command defers its app, and nothing else
        "roadtwin_core/render/__init__.py:3 numpy",   # on the GPU side, anything but numpy may wait
        "roadtwin_core/x.py:7 roadtwin_core.y", "roadtwin_core/x.py:8 re",
        "roadtwin_core/x.py:10 scipy.spatial.cKDTree", "roadtwin_core/x.py:11 pxr.Usd"]


# --------------------------------------------------------------------------- layers
def _framework(path: str) -> bool:
    return path.startswith("roadtwin_core/") and not path.startswith(("roadtwin_core/apps/", "roadtwin_core/cli/"))


def test_the_framework_imports_no_app_and_not_the_command_line():
    """``roadtwin_core`` outside ``apps/`` and ``cli/`` is what apps and plugins build on; an
    import the other way (at the top or in a function) would tie it to one command."""
    bad = [i for found in all_imports().values() for i in found
           if _framework(i.path) and i.module.split(".")[:2] in (["roadtwin_core", "apps"], ["roadtwin_core", "cli"])]
    assert not bad, "the framework imports an app or the command line:\n" + "\n".join(f"  {i}" for i in bad)


def test_only_the_command_line_imports_the_command_line():
    """Apps are what a Python user calls; the command line only parses options and calls them."""
    bad = [i for found in all_imports().values() for i in found
           if not i.path.startswith("roadtwin_core/cli/") and i.module.split(".")[:2] == ["roadtwin_core", "cli"]]
    assert not bad, "imports the command line:\n" + "\n".join(f"  {i}" for i in bad)


def test_core_imports_no_plugin_and_no_plugin_imports_another():
    plugins = {p.name for p in PLUGINS.iterdir() if (p / "__init__.py").exists()}
    assert {"roadtwin_defects", "roadtwin_cdt"} <= plugins
    bad = []
    for found in all_imports().values():
        for i in found:
            own = i.path.split("/")[1] if i.path.startswith("plugins/") else None
            if i.top in plugins and i.top != own:
                bad.append(f"  {i}" + ("" if own else "  (the core)"))
    assert not bad, "the core imports a plugin, or a plugin another:\n" + "\n".join(bad)


# --------------------------------------------------------------------------- light entry points
def _third_party_loaded(modules: str) -> list[str]:
    """Top-level third-party packages in ``sys.modules`` after importing ``modules`` in a fresh
    interpreter."""
    code = (f"import sys, json\nimport {modules}\n"
            "std = set(sys.stdlib_module_names)\n"
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} - std)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    return [m for m in json.loads(out.stdout) if not m.startswith("_") and not m.startswith("roadtwin")]


@pytest.mark.parametrize("package, allowed", [
    ("roadtwin_core.vehicle", {"numpy"}),
    ("roadtwin_core.render", {"numpy", "shapely"}),
    ("roadtwin_core.warp_runtime", set()),
    ("roadtwin_core.apps.render", {"numpy", "shapely", "PIL", "pluggy"}),
])
def test_gpu_side_packages_stay_light(package, allowed):
    """What the warp kernels import runs on a GPU machine with numpy and warp only (shapely for the
    render scene's ground polygons): USD, scipy and the plugin manager load inside the functions
    that need them. Ray's render workers run there too and import ``roadtwin_core.apps.render``
    (Pillow for the sensor model's JPEG, pluggy for the plugin manager it holds), so loading its
    stage (USD) and the ego-lane labels (scipy) wait as well (:data:`LAZY_INTERNAL`)."""
    extra = sorted(set(_third_party_loaded(package)) - allowed - {"cython_runtime"})
    assert not extra, f"importing {package} loads {extra}"


def test_the_command_line_loads_no_usd_scipy_or_plots():
    """``roadtwin --help`` imports the command line only; the apps (USD, scipy, matplotlib: ~0.7 s
    more than the help's own ~0.13 s) load when a command runs."""
    heavy = {"pxr", "scipy", "matplotlib", "trimesh", "torch", "warp", "open3d", "cv2"}
    loaded = sorted(heavy & set(_third_party_loaded("roadtwin_core.cli")))
    assert not loaded, f"importing roadtwin_core.cli (what `roadtwin --help` runs) loads {loaded}"
