"""Texture sets served from the cache are the bytes a fresh generation writes; a damaged entry is
regenerated, never served; a different seed or changed code misses."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from roadtwin_core.looks import write_textures
from roadtwin_core.looks import cache as tcache
from roadtwin_core.looks.cache import write_textures_cached

SIZE = 64   # the smallest set: the cache logic does not depend on size


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("ROADTWIN_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "textures"


def test_cached_set_is_byte_identical_and_skips_generation(tmp_path, cache_dir, monkeypatch):
    fresh = write_textures(tmp_path / "fresh", seed=5, size=SIZE)
    first = write_textures_cached(tmp_path / "a", seed=5, size=SIZE)       # miss: generates, stores
    assert len(list(cache_dir.iterdir())) == 1

    def boom(*a, **k):
        raise AssertionError("a cache hit must not generate")

    monkeypatch.setattr(tcache, "write_textures", boom)
    second = write_textures_cached(tmp_path / "b", seed=5, size=SIZE)      # hit
    assert digests(tmp_path / "a") == digests(tmp_path / "b") == digests(tmp_path / "fresh")
    assert first == second == fresh


def test_damaged_entry_is_regenerated(tmp_path, cache_dir):
    write_textures_cached(tmp_path / "a", seed=1, size=SIZE)
    entry = next(cache_dir.iterdir())
    victim = sorted(entry.glob("*.png"))[0]
    victim.write_bytes(victim.read_bytes()[:-10])                          # truncated file
    write_textures_cached(tmp_path / "b", seed=1, size=SIZE)
    assert digests(tmp_path / "b") == digests(tmp_path / "a")
    assert hashlib.sha256(victim.read_bytes()).hexdigest() == digests(tmp_path / "a")[victim.name]  # re-stored


def test_key_covers_seed_and_code(tmp_path, cache_dir, monkeypatch):
    write_textures_cached(tmp_path / "a", seed=1, size=SIZE)
    write_textures_cached(tmp_path / "b", seed=2, size=SIZE)
    assert digests(tmp_path / "a") != digests(tmp_path / "b")
    monkeypatch.setattr(tcache, "code_fingerprint", lambda: "changed-code")
    write_textures_cached(tmp_path / "c", seed=1, size=SIZE)
    assert len(list(cache_dir.iterdir())) == 3


def test_empty_cache_dir_turns_the_cache_off(tmp_path, monkeypatch):
    monkeypatch.setenv("ROADTWIN_CACHE_DIR", "")
    assert tcache.cache_root() is None
    write_textures_cached(tmp_path / "a", seed=1, size=SIZE)
    assert digests(tmp_path / "a") == digests(Path(write_textures(tmp_path / "b", seed=1, size=SIZE) and tmp_path / "b"))
