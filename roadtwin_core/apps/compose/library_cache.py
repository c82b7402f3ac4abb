"""The compose library's models cached on disk: a warm Town01 compose skips generating and
coarsening its ~70 parametric models (~1.4 CPU s, plus a forked pool and its imports).

Why it is safe: a model depends only on (seed, type, index, road edge, the type's priors) and on
the code that makes it. The key holds all of them: the inputs, and a fingerprint of the code, the
files of the package that defines the defect type (a plugin's whole folder), of roadtwin_core's
modules that build and coarsen models, and the versions of the libraries that shape the numbers
(numpy, Triangle, shapely, matplotlib). An edited generator misses the cache; an entry is a
pickled :class:`~roadtwin_core.model.DefectModel` whose SHA-256 is checked on every read, so a
damaged or partial entry is made again. The models are the same objects either way, so the
stage's bytes do not depend on the cache (tested).

Where: ``$ROADTWIN_CACHE_DIR/library`` (an empty value turns every cache off), else the user
cache folder (``~/.cache/roadtwin/library``), like the textures' cache.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import os
import pickle
import sys
import tempfile
from pathlib import Path

from ...looks.cache import cache_root
from ...model import DefectModel

CORE_SOURCES = ("model.py", "remesh.py", "geometry.py", "params.py", "town/param_priors.py")
BIG_FILE = 1 << 20           # bytes: larger files of a plugin's folder are fingerprinted by size and time
LIBRARIES = ("numpy", "triangle", "shapely", "matplotlib", "manifold3d", "scipy")


def library_cache_root() -> Path | None:
    """The folder, or None when ``ROADTWIN_CACHE_DIR`` is set to an empty value."""
    textures = cache_root()
    return textures.parent / "library" if textures is not None else None


@functools.lru_cache(maxsize=None)
def _folder_fingerprint(folder: str) -> str:
    h = hashlib.sha256()     # every file: a type may read its shapes or priors from data beside its code
    for src in sorted(p for p in Path(folder).rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        stat = src.stat()       # a large data file by its size and time, not read on every compose
        body = src.read_bytes() if stat.st_size <= BIG_FILE else f"{stat.st_size} {stat.st_mtime_ns}".encode()
        h.update(str(src.relative_to(folder)).encode() + b"\0" + body + b"\0")
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _core_fingerprint() -> str:
    core = Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for name in CORE_SOURCES:
        h.update(name.encode() + b"\0" + (core / name).read_bytes() + b"\0")
    for lib in LIBRARIES:
        try:
            version = importlib.metadata.version(lib)
        except importlib.metadata.PackageNotFoundError:
            version = "absent"
        h.update(f"{lib} {version}\0".encode())
    h.update(f"python {sys.version_info[:2]}".encode())
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _file_fingerprint(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def type_fingerprint(defect_type) -> str | None:
    """The code fingerprint of a registered defect type: its defining package's files (a module
    outside a package: that file). None when its code has no file (made at run time): not cached."""
    name = type(defect_type).__module__
    path = getattr(sys.modules.get(name), "__file__", None)
    if not path:
        return None
    folders = list(getattr(sys.modules.get(name.split(".")[0]), "__path__", None) or [])
    code = _folder_fingerprint(str(Path(folders[0]).resolve())) if folders else _file_fingerprint(str(Path(path).resolve()))
    return f"{code}:{_core_fingerprint()}"


def model_key(defect_type, type_name: str, index: int, seed: int, road_edge_m: float, priors) -> str | None:
    """The cache key of one library model, or None when it cannot be cached."""
    code = type_fingerprint(defect_type)
    if code is None:
        return None
    inputs = {"type": type_name, "class": f"{type(defect_type).__module__}.{type(defect_type).__qualname__}",
              "index": int(index), "seed": int(seed), "road_edge_m": repr(float(road_edge_m)),
              "priors": repr(sorted((priors or {}).items())), "code": code}
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()[:32]


def load_model(root: Path, key: str) -> DefectModel | None:
    """The cached model, or None (no entry, or a damaged one)."""
    try:
        data = (root / f"{key}.pkl").read_bytes()
        digest, payload = data[:64].decode(), data[64:]
        if hashlib.sha256(payload).hexdigest() != digest:
            return None
        model = pickle.loads(payload)
        return model if isinstance(model, DefectModel) else None
    except (OSError, ValueError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, UnicodeDecodeError):
        return None


def store_model(root: Path, key: str, model: DefectModel) -> None:
    """Best effort, atomic: a read-only or full cache never fails a compose, and a reader never
    sees half an entry."""
    payload = pickle.dumps(model, protocol=pickle.HIGHEST_PROTOCOL)
    try:
        root.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f"{key}.", suffix=".tmp", dir=root)
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(hashlib.sha256(payload).hexdigest().encode() + payload)
        os.replace(tmp, root / f"{key}.pkl")
    except OSError:
        Path(tmp).unlink(missing_ok=True)


__all__ = ["library_cache_root", "load_model", "model_key", "store_model", "type_fingerprint"]
