"""Output folders after a crash: a run killed with SIGKILL leaves its hidden temporary folder;
the next run for the same output removes it (and only folders of dead processes)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from roadtwin_core.atomic import atomic_output_dir

HOLD = """
import sys, time
from roadtwin_core.atomic import atomic_output_dir
with atomic_output_dir(sys.argv[1]) as tmp:
    (tmp / "half.txt").write_text("half-written")
    print(tmp, flush=True)
    time.sleep(60)
"""


def _start_holder(out: Path) -> tuple[subprocess.Popen, Path]:
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    tmp = Path(proc.stdout.readline().strip())
    assert tmp.is_dir() and tmp.name == f".{out.name}.tmp-{proc.pid}"
    return proc, tmp


def test_kill_9_litter_is_removed_by_the_next_run_live_runs_are_kept(tmp_path):
    out = tmp_path / "town"
    with atomic_output_dir(out) as t:
        (t / "result.txt").write_text("earlier output")
    killed, stale = _start_holder(out)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    assert stale.is_dir()                                  # SIGKILL: no cleanup ran
    live, running = _start_holder(out)
    try:
        with atomic_output_dir(out) as t:
            assert not stale.exists() and running.is_dir()   # dead run's folder gone, live one kept
            (t / "result.txt").write_text("new output")
        assert (out / "result.txt").read_text() == "new output"
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["town", running.name])
    finally:
        live.kill()
        live.wait()


def test_a_run_killed_between_its_renames_gives_the_earlier_output_back(tmp_path):
    out = tmp_path / "town"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    old = tmp_path / f".town.old-{dead.pid}"                  # what such a crash leaves: no town/
    old.mkdir()
    (old / "result.txt").write_text("earlier output")
    with pytest.raises(RuntimeError, match="fails too"), atomic_output_dir(out):
        assert (out / "result.txt").read_text() == "earlier output"
        raise RuntimeError("this run fails too")
    assert (out / "result.txt").read_text() == "earlier output" and not old.exists()


def test_file_outputs_share_the_crash_cleanup_and_leave_nothing_on_error(tmp_path):
    from roadtwin_core.atomic import atomic_files, atomic_write_bytes

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    out = tmp_path / "road.crg"
    litter = tmp_path / f".road.tmp-{dead.pid}.crg"            # what a kill -9 mid-write leaves
    litter.write_bytes(b"half")
    live = tmp_path / f".road.tmp-{os.getppid()}.crg"          # a running process's: kept
    live.write_bytes(b"busy")
    atomic_write_bytes(out, b"whole")
    assert out.read_bytes() == b"whole" and not litter.exists() and live.exists()
    with pytest.raises(RuntimeError), atomic_files(out, tmp_path / "road.mtl") as (a, b):
        a.write_bytes(b"new")
        b.write_bytes(b"new")
        raise RuntimeError("writer failed")
    assert out.read_bytes() == b"whole" and not (tmp_path / "road.mtl").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["road.crg", live.name])


def test_a_killed_composes_texture_staging_is_removed_by_the_next_run(tmp_path):
    """The composer's helper stages textures beside the output (scratch_dir): a kill -9 leaves
    that folder too, and the next run for the same output removes it, not a live run's."""
    hold = ("import sys, time\nfrom roadtwin_core.atomic import scratch_dir\n"
            "print(scratch_dir(sys.argv[1], 'textures'), flush=True)\ntime.sleep(60)\n")
    out = tmp_path / "town"
    procs = [subprocess.Popen([sys.executable, "-c", hold, str(out)], stdout=subprocess.PIPE, text=True)
             for _ in range(2)]
    killed, live = procs
    try:
        stale, running = (Path(p.stdout.readline().strip()) for p in procs)
        assert stale.name == f".town.tmp-textures-{killed.pid}" and stale.is_dir()
        killed.send_signal(signal.SIGKILL)
        killed.wait()
        with atomic_output_dir(out) as t:
            (t / "result.txt").write_text("output")
        assert not stale.exists() and running.is_dir()
    finally:
        live.kill()
        live.wait()
