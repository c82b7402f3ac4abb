"""The real ``roadtwin`` command line in a subprocess (:func:`run_cli`) or through its entry point
in this process (:func:`run_main`: the same error mapping, without the ~3 s of a fresh
interpreter and its imports), and the check every bad-input test makes of it: one line on stderr
naming what is wrong, exit 2, no traceback. Shared by the tests of the commands (importable from
every test folder: tests/conftest.py)."""
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


def run_main(argv: list[str], capsys, monkeypatch) -> tuple[int, str, str]:
    """``roadtwin ARGV`` in-process through the real entry point (its error mapping included):
    (exit code, stdout, stderr)."""
    from roadtwin_core import cli

    monkeypatch.delenv("ROADTWIN_DEBUG", raising=False)
    monkeypatch.delenv("ROADTWIN_PLUGINS", raising=False)
    monkeypatch.setattr(sys, "argv", ["roadtwin", *map(str, argv)])
    capsys.readouterr()
    try:
        cli.main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out, err = capsys.readouterr()
    return code, out, err


def one_line(r: subprocess.CompletedProcess, *needles: str) -> str:
    err = r.stderr.strip()
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "\n" not in err and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err
