"""`roadtwin sweep --rerun` writes a rerun recording (.rrd) of the IMU channels."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def test_sweep_writes_a_readable_rerun_recording(tmp_path):
    pytest.importorskip("rerun")
    exe = Path(sys.executable).with_name("roadtwin")
    out = tmp_path / "sweep"
    proc = subprocess.run([str(exe), "sweep", "--surface", "iso8608:B", "--length", "40", "--speeds", "20:30:10",
                           "--rerun", "--no-plots", "-o", str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    rrd = out / "sweep.rrd"
    data = rrd.read_bytes()
    assert data[:4] == b"RRF2"  # rerun's RRD stream header
    assert len(data) > 1000
    # The logged entity paths are stored in the stream: one per IMU channel of every run.
    for channel in (b"/az", b"/wx", b"/wy"):
        assert channel in data
