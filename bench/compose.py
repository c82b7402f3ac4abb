"""Compose benchmark: wall time, peak memory and the place / merge / write split.

For each defect count, one fresh Python process composes the layout (``roadtwin_core.apps.compose.run``,
the function behind ``roadtwin compose``) into a temporary directory and reports its own peak
RSS (``ru_maxrss``; ``worker_MB`` is the largest merge worker process, when the merge runs in a
process pool), so every figure belongs to that run alone. The wall time is the whole child
process (interpreter start and imports included); ``compose_s`` is the compose call alone.

    .venv/bin/python bench/compose.py                      # stages/town.usda, 100 and 1,000 defects
    .venv/bin/python bench/compose.py --counts 100 400 --surface flat --preview
    .venv/bin/python bench/compose.py --executor serial     # merge in the one process

The surface is the layout's own (``roadtwin:rules:surface``; iso8608:B:0.1 on the sample town)
unless ``--surface`` says otherwise. A count that does not fit prints the composer's message
("only k of N defects fit ...") in place of the figures. Not a test: it asserts nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# Runs in the child: compose once, print one JSON line with the figures (or the error).
CHILD = r"""
import json, resource, sys, time
from roadtwin_core import RoadtwinError
from roadtwin_core.apps.compose.run import compose
layout, out, n, seed, surface, preview, extra = sys.argv[1:8]
kwargs = json.loads(extra)  # executor / workers, only when asked for
t0 = time.perf_counter()
try:
    res = compose(layout, out, defects=int(n), seed=None if seed == "-" else int(seed),
                  surface=None if surface == "-" else surface, preview=preview == "1", **kwargs)
    result = {"ok": True, "summary": res.summary}
except RoadtwinError as exc:
    result = {"ok": False, "error": str(exc)}
result["compose_s"] = time.perf_counter() - t0
# ru_maxrss is in KiB on Linux. SELF: this process; CHILDREN: the largest single worker process
# it waited for (the merge may run in a process pool), not a sum.
result["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
result["worker_maxrss_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
print("BENCH " + json.dumps(result))
"""


def run_one(layout: Path, count: int, seed: int | None, surface: str | None, preview: bool,
            extra: dict) -> dict:
    with tempfile.TemporaryDirectory(prefix="roadtwin-bench-") as tmp:
        cmd = [sys.executable, "-c", CHILD, str(layout), str(Path(tmp) / "out"), str(count),
               "-" if seed is None else str(seed), surface or "-", "1" if preview else "0", json.dumps(extra)]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
        wall = time.perf_counter() - t0
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("BENCH ")), None)
    if proc.returncode or line is None:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"ok": False, "error": f"child failed (exit {proc.returncode}): {tail}", "wall_s": wall}
    result = json.loads(line[len("BENCH "):])
    result["wall_s"] = wall
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layout", type=Path, default=REPO / "stages" / "town.usda")
    ap.add_argument("--counts", type=int, nargs="+", default=[100, 1000], help="defect counts, one run each")
    ap.add_argument("--seed", type=int, default=None, help="default: the layout's seed")
    ap.add_argument("--surface", default=None, help="default: the layout's surface rule")
    ap.add_argument("--preview", action="store_true", help="also render preview.png (off: not in the split)")
    ap.add_argument("--executor", default=None, help="merge executor (local, serial, ...); default: compose's")
    ap.add_argument("--workers", type=int, default=None, help="merge worker processes; default: compose's")
    args = ap.parse_args()
    extra = {k: v for k, v in (("executor", args.executor), ("workers", args.workers)) if v is not None}

    print(f"roadtwin compose bench: {args.layout.relative_to(REPO) if args.layout.is_relative_to(REPO) else args.layout}"
          f", surface {args.surface or 'from layout'}, seed {args.seed if args.seed is not None else 'from layout'}"
          f", preview {'on' if args.preview else 'off'}"
          + "".join(f", {k} {v}" for k, v in extra.items()))
    print(f"python {platform.python_version()}, {os.cpu_count()} CPUs, {platform.machine()}")
    head = (f"{'defects':>8} {'wall_s':>7} {'compose_s':>9} {'peak_MB':>8} {'worker_MB':>9} {'segments':>8} {'placed':>6} "
            f"{'triangles':>9} {'place_s':>7} {'merge_s':>7} {'write_s':>7}")
    print(head)
    print("-" * len(head))
    for n in args.counts:
        r = run_one(args.layout, n, args.seed, args.surface, args.preview, extra)
        if r["ok"]:
            s, t = r["summary"], r["summary"]["timings_s"]
            print(f"{n:>8} {r['wall_s']:>7.2f} {r['compose_s']:>9.2f} {r['maxrss_mb']:>8.0f} "
                  f"{r['worker_maxrss_mb']:>9.0f} {s['segments']:>8} "
                  f"{s['defects']:>6} {s['triangles']:>9} {t['place_s']:>7.2f} {t['merge_s']:>7.2f} "
                  f"{t['write_s']:>7.2f}")
        else:
            rss = (f"{r['maxrss_mb']:>8.0f} {r['worker_maxrss_mb']:>9.0f}" if "maxrss_mb" in r
                   else f"{'-':>8} {'-':>9}")
            print(f"{n:>8} {r['wall_s']:>7.2f} {r.get('compose_s', float('nan')):>9.2f} {rss}  FAILED: {r['error']}")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
