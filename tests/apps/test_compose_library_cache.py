"""The compose library's cache (roadtwin_core/apps/compose/library_cache.py): a warm compose makes
no model and writes the same bytes as a compose without any cache; a damaged entry is made
again; an edited generator misses the cache."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from lane_layout import write_lane_layout
from roadtwin_core.apps.compose import library_cache, run


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "summary.json"}      # summary.json holds the run's timings


@pytest.fixture
def counted(monkeypatch):
    """Counts the library models actually made (serial executor: in this process)."""
    made = []
    original = run._library_model

    def counting(context, item):
        made.append(item)
        return original(context, item)

    monkeypatch.setattr(run, "_library_model", counting)
    return made


def test_warm_cache_makes_no_model_and_writes_the_same_stage(tmp_path, monkeypatch, counted):
    layout = write_lane_layout(tmp_path / "road.usda", 10, 2, "crack")
    monkeypatch.setenv("ROADTWIN_CACHE_DIR", "")
    run.compose(layout, tmp_path / "uncached", preview=False, executor="serial")
    n_models = len(counted)
    assert n_models > 0
    monkeypatch.setenv("ROADTWIN_CACHE_DIR", str(tmp_path / "cache"))
    run.compose(layout, tmp_path / "cold", preview=False, executor="serial")
    assert len(counted) == 2 * n_models
    entries = sorted((tmp_path / "cache" / "library").glob("*.pkl"))
    assert len(entries) == n_models
    run.compose(layout, tmp_path / "warm", preview=False, executor="serial")
    assert len(counted) == 2 * n_models                        # nothing made
    reference = _files(tmp_path / "uncached")
    assert _files(tmp_path / "cold") == reference and _files(tmp_path / "warm") == reference
    # a damaged entry (cut short, as by a full disk) is made again, and the stage stays the same
    entries[0].write_bytes(entries[0].read_bytes()[:100])
    run.compose(layout, tmp_path / "mended", preview=False, executor="serial")
    assert len(counted) == 2 * n_models + 1
    assert _files(tmp_path / "mended") == reference
    # another seed is other models: made, not served
    run.compose(layout, tmp_path / "seed9", seed=9, preview=False, executor="serial")
    assert len(counted) == 3 * n_models + 1


def test_an_edited_generator_misses_the_cache(tmp_path, monkeypatch):
    pkg = tmp_path / "edited_defects"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from .shapes import Bowl\n")
    (pkg / "shapes.py").write_text("class Bowl:\n    depth = 0.05\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("edited_defects")
    key = library_cache.model_key(module.Bowl(), "pothole", 0, 1, 0.5, None)
    assert key == library_cache.model_key(module.Bowl(), "pothole", 0, 1, 0.5, None)
    assert key != library_cache.model_key(module.Bowl(), "pothole", 1, 1, 0.5, None)      # another index
    assert key != library_cache.model_key(module.Bowl(), "pothole", 0, 2, 0.5, None)      # another seed
    (pkg / "shapes.py").write_text("class Bowl:\n    depth = 0.07\n")                  # the generator edited
    library_cache._folder_fingerprint.cache_clear()
    assert library_cache.model_key(module.Bowl(), "pothole", 0, 1, 0.5, None) != key
    for name in [m for m in sys.modules if m.startswith("edited_defects")]:
        del sys.modules[name]


def test_a_cache_that_cannot_be_written_does_not_fail_a_compose(tmp_path, monkeypatch):
    layout = write_lane_layout(tmp_path / "road.usda", 6, 2, "crack")
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache folder would go")
    monkeypatch.setenv("ROADTWIN_CACHE_DIR", str(blocker))
    result = run.compose(layout, tmp_path / "out", preview=False, executor="serial")
    assert result.town.exists()
