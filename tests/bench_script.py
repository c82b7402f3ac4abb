"""A bench/ script loaded as a module by its path (bench/ is not a package), so tests call its
functions: registered in sys.modules first (dataclasses look their module up)."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"


def load_bench_script(name: str):
    """``bench/NAME.py`` as module ``bench_NAME`` (executed anew on each call)."""
    spec = importlib.util.spec_from_file_location(f"bench_{name.lstrip('_')}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod
