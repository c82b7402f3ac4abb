"""The real ``roadtwin`` command line in a subprocess, and the check every bad-input test makes of
it: one line on stderr naming what is wrong, exit 2, no traceback. Shared by the tests of the
reconstruct commands (importable from every test folder: tests/conftest.py)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_cli(*args) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("ROADTWIN_PLUGINS", "ROADTWIN_DEBUG")}
    return subprocess.run([sys.executable, "-m", "roadtwin_core.cli", *map(str, args)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)


def one_line(r: subprocess.CompletedProcess, *needles: str) -> str:
    err = r.stderr.strip()
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "\n" not in err and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err
