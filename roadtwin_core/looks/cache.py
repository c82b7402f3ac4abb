"""Texture sets cached by seed: a compose copies ~14 MB of PNG instead of spending ~3 s of CPU.

Why a cache and not a shared folder: every town folder stays self-contained (textures written
next to the stage, docs/architecture.md#looks-and-texture-coordinates), so a cached set is
*copied* in. The key is the seed, the size, and a fingerprint of the code that makes the bytes
(every module of this package, plus the numpy, Pillow and zlib versions and the PNG encoder that
generate and encode them), so a changed generator or encoder misses the cache instead of serving
stale textures. Each cached file's SHA-256 is in the manifest and checked on every copy; a
damaged or partial entry is regenerated.

Where: ``$ROADTWIN_CACHE_DIR/textures`` when that is set (an empty value turns the cache off),
else the user cache dir (``~/.cache/roadtwin/textures`` on Linux).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import zlib
from dataclasses import asdict
from pathlib import Path

import numpy
import PIL

try:                    # not a declared dependency: the XDG folder when it is missing
    import platformdirs
except ImportError:
    platformdirs = None

from .catalog import MaterialSpec
from .textures import DEFAULT_SIZE, png_encoder, write_textures

_MANIFEST = "manifest.json"


def cache_root() -> Path | None:
    """The cache folder, or None when ``ROADTWIN_CACHE_DIR`` is set to an empty value."""
    env = os.environ.get("ROADTWIN_CACHE_DIR")
    if env is not None:
        return Path(env) / "textures" if env.strip() else None
    if platformdirs is not None:
        base = Path(platformdirs.user_cache_dir("roadtwin"))
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "roadtwin"
    return base / "textures"


def code_fingerprint() -> str:
    """Hash of the texture code (this package's sources) and of the libraries that shape the bytes."""
    h = hashlib.sha256()
    for src in sorted(Path(__file__).parent.glob("*.py")):
        h.update(src.name.encode() + b"\0" + src.read_bytes() + b"\0")
    h.update(f"numpy {numpy.__version__} pillow {PIL.__version__} png {png_encoder()} zlib {zlib.ZLIB_VERSION}".encode())
    return h.hexdigest()[:16]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_textures_cached(folder: str | Path, seed: int = 0, size: int = DEFAULT_SIZE,
                          generate=None) -> dict[str, MaterialSpec]:
    """:func:`write_textures`, served from the cache when this seed and size were made before
    by the same code (byte-identical files: they are that run's bytes, checked by hash).
    ``generate``: another texture writer (same signature) to call instead, uncached."""
    root = cache_root()
    if generate is not None and generate is not write_textures:
        return generate(folder, seed) if size == DEFAULT_SIZE else generate(folder, seed, size)
    if root is None:
        return write_textures(folder, seed, size)
    folder = Path(folder)
    entry = root / f"seed{int(seed)}-size{int(size)}-{code_fingerprint()}"
    specs = _copy_from(entry, folder)
    if specs is not None:
        return specs
    specs = write_textures(folder, seed, size)
    _store(entry, folder, specs)
    return specs


def _copy_from(entry: Path, folder: Path) -> dict[str, MaterialSpec] | None:
    try:
        manifest = json.loads((entry / _MANIFEST).read_text())
        folder.mkdir(parents=True, exist_ok=True)
        for name, digest in sorted(manifest["files"].items()):
            data = (entry / name).read_bytes()
            if hashlib.sha256(data).hexdigest() != digest:
                raise ValueError(f"{name}: hash mismatch")
            (folder / name).write_bytes(data)
        return {k: MaterialSpec(**v) for k, v in manifest["specs"].items()}
    except (OSError, ValueError, KeyError, TypeError):
        return None          # no entry, or a damaged one: the caller regenerates (and re-stores)


def _store(entry: Path, folder: Path, specs: dict[str, MaterialSpec]) -> None:
    """Best effort: a read-only or full cache never fails a compose. Written to a temporary
    folder and renamed, so a reader never sees half an entry."""
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=entry.name + ".", dir=entry.parent))
    except OSError:
        return
    try:
        files = {}
        for p in sorted(folder.iterdir()):
            if p.is_file():
                shutil.copyfile(p, tmp / p.name)
                files[p.name] = _sha256(tmp / p.name)
        manifest = {"files": files, "specs": {k: asdict(v) for k, v in specs.items()}}
        (tmp / _MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True))
        shutil.rmtree(entry, ignore_errors=True)       # a damaged entry
        os.replace(tmp, entry)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)

__all__ = ["cache_root", "code_fingerprint", "write_textures_cached"]
