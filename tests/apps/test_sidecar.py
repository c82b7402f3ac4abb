"""The composer's helper process: jobs run in order on another core; handing a job over never waits
for an earlier one; errors come back as errors; a dead helper is reported, not waited for; a compose
that fails stops its helper and leaves nothing behind."""
from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import roadtwin_core.apps.compose.run as compose_module
from roadtwin_core.errors import RoadtwinError
from roadtwin_core.apps.compose.sidecar import Sidecar

REPO = Path(__file__).resolve().parents[2]


def wait_for_file(path: Path, limit_s: float = 20.0) -> float:
    t0 = time.perf_counter()
    while not path.exists():
        if time.perf_counter() - t0 > limit_s:
            raise TimeoutError(path)
        time.sleep(0.01)
    return time.perf_counter() - t0


def checksum(a: np.ndarray) -> int:
    return int(a.sum())


def fail_plainly(message: str):
    raise RoadtwinError(message)


def crash():
    raise ZeroDivisionError("boom")


def test_jobs_run_in_order_and_handing_over_does_not_wait(tmp_path):
    gate = tmp_path / "gate"
    big = np.ones(40_000_000 // 8)               # 40 MB: far more than a pipe holds
    with Sidecar() as side:
        first = side.submit(wait_for_file, gate)
        t0 = time.perf_counter()
        second = side.submit(checksum, big)      # the helper is blocked in the first job
        handed_over_s = time.perf_counter() - t0
        assert handed_over_s < 2.0
        gate.touch()
        assert side.result(second) == len(big)   # results can be collected in any order
        assert side.result(first) >= 0.0


def test_errors_come_back_as_errors():
    with Sidecar() as side:
        bad_input, bug = side.submit(fail_plainly, "layout.usda: no roads"), side.submit(crash)
        with pytest.raises(RoadtwinError, match="^layout.usda: no roads$"):
            side.result(bad_input)
        with pytest.raises(RuntimeError, match="ZeroDivisionError: boom"):
            side.result(bug)


def test_a_dead_helper_is_reported_not_waited_for(tmp_path):
    with Sidecar() as side:
        ticket = side.submit(wait_for_file, tmp_path / "never")
        time.sleep(0.5)
        os.kill(side._proc.pid, signal.SIGKILL)
        t0 = time.perf_counter()
        with pytest.raises(RoadtwinError, match="helper process ended unexpectedly"):
            side.result(ticket)
        assert time.perf_counter() - t0 < 5.0


def test_a_failed_compose_stops_its_helper_and_writes_nothing(tmp_path, monkeypatch):
    def fails_after_the_preview_started(town):
        raise RoadtwinError("validation refused on purpose")

    monkeypatch.setattr(compose_module, "validate_stage", fails_after_the_preview_started)
    out = tmp_path / "out"
    with pytest.raises(RoadtwinError, match="on purpose"):
        compose_module.compose(REPO / "stages" / "town.usda", out, defects=5, seed=1, executor="serial")
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert multiprocessing.active_children() == []


def test_the_preview_made_in_the_helper_is_in_the_output(tmp_path):
    res = compose_module.compose(REPO / "stages" / "town.usda", tmp_path / "out", defects=5, seed=1,
                                 executor="serial")
    png = res.outdir / "preview.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    timings = json.loads((res.outdir / "summary.json").read_text())["timings_s"]
    assert timings["preview_s"] > 0 and 0 <= timings["preview_wait_s"]
    assert multiprocessing.active_children() == []


def test_a_helper_told_to_end_still_hands_over_its_results(tmp_path):
    with Sidecar() as side:
        tickets = [side.submit(checksum, np.arange(n)) for n in (10, 1000)]
        side.end_when_done()
        side._proc.join(20)
        assert not side._proc.is_alive()
        assert [side.result(t) for t in tickets] == [45, 499500]


def test_only_warps_no_cuda_driver_notice_is_dropped(capfd):
    from roadtwin_core.warp_runtime import without_cuda_driver_notice

    with without_cuda_driver_notice():
        os.write(2, b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. GPU execution will not be "
                    b"available.\n")
        os.write(2, b"kernel cache: something else\n")
        print("python stderr line", file=sys.stderr)
    err = capfd.readouterr().err
    assert "NVIDIA CUDA driver" not in err
    assert "kernel cache: something else\n" in err and "python stderr line\n" in err


def shout(text: str) -> int:
    print(text)
    os.write(2, f"{text} (native)\n".encode())
    return 1


def test_what_a_helper_prints_is_kept_until_asked_for(capfd):
    with Sidecar() as side:
        assert side.result(side.submit(shout, "library warning")) == 1
        assert capfd.readouterr().err == ""                       # nothing shown while it works
        assert side.output() == "library warning\nlibrary warning (native)\n"
        side.replay_output()
        assert capfd.readouterr().err == "library warning\nlibrary warning (native)\n"


def test_a_dead_helpers_last_line_names_what_happened(tmp_path):
    with Sidecar() as side:
        side.submit(shout, "about to be killed")
        ticket = side.submit(wait_for_file, tmp_path / "never")
        # killed once it has run the first job (its line is in the log), however long starting took
        t0 = time.perf_counter()
        while not side.output().endswith("about to be killed (native)\n"):
            assert time.perf_counter() - t0 < 120.0, f"the helper ran no job in 120 s: {side.output()!r}"
            time.sleep(0.02)
        os.kill(side._proc.pid, signal.SIGKILL)
        with pytest.raises(RoadtwinError, match=r"exit code -9\): about to be killed \(native\)$"):
            side.result(ticket)


def test_a_script_without_a_main_guard_can_compose(tmp_path):
    """A spawned helper would run the parent's unguarded script again (multiprocessing's rule)."""
    script = tmp_path / "make_town.py"
    script.write_text("from roadtwin_core.apps.compose.run import compose\n"
                      f"res = compose({str(REPO / 'stages' / 'town.usda')!r}, {str(tmp_path / 'out')!r}, defects=2, seed=1)\n"
                      "print('made', res.town.name)\n")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "made town.usda"
    assert (tmp_path / "out" / "preview.png").is_file()


def test_a_helper_leaves_nothing_for_the_resource_tracker(monkeypatch):
    """Named semaphores (a multiprocessing.Queue's locks) stay with the resource tracker; a helper
    stopped while it starts could leave it warning about "leaked semaphores" after bad input's one
    line of error (seen in CI). The helper's channels must hold no such resource."""
    from multiprocessing import resource_tracker

    registered = []
    monkeypatch.setattr(resource_tracker, "register", lambda name, rtype: registered.append((name, rtype)))
    with Sidecar() as side:
        assert side.result(side.submit(checksum, np.arange(4))) == 6
    with Sidecar():
        pass                                      # stopped while it starts
    assert registered == []
