"""Town01 at paper scale: the default ``roadtwin compose`` command's wall time, peak memory,
phase split and output size, for 1,000 and 10,000 defects, in one run.

    .venv/bin/python bench/town.py                       # 1,000 and 10,000 defects
    .venv/bin/python bench/town.py --counts 1000 --executor ray
    .venv/bin/python bench/town.py --counts 1000 --preview-cost 3   # + what the preview adds
    .venv/bin/python bench/town.py --counts 1000 --props-cost 3     # + what the props add (time, memory, size)
    .venv/bin/python bench/town.py --counts 1000 --lookalikes --repeats 3 --wait-idle   # issue 22's bar, shared machine

Import: ``roadtwin import opendrive tests/data/opendrive/Town01.xodr`` in a fresh process (wall
time, including interpreter start). Compose: the plain CLI, ``roadtwin compose town01.usda
--defects N -o OUT`` (preview included, default executor), one fresh process per count, exactly
what a user types. ``wall_s`` is that whole process (interpreter start and imports included);
``peak_MB`` the largest memory of the command's process tree at any moment: the sum of each
process's proportional set size (PSS: a page shared by k processes counts 1/k in each, so pages a
forked merge worker shares with the CLI are counted once), sampled every 0.2 s with psutil over
the CLI process, its merge workers and its helper process (reading it costs ~3 ms a process); ``rss_MB`` the same with resident set
sizes, sampled every 20 ms (shared pages counted in every process: an upper bound); ``main_MB`` the CLI process's own
``ru_maxrss``. The phase split is the composer's ``timings_s`` (``summary.json``): place / merge /
markings / textures / write / validate / preview (its own time, in the helper process, overlapping write and validate) / preview_wait (what the composer waited for it at the end); ``size_MB`` is everything under the output
folder. Textures come from the user cache after the first run on a machine (``textures_s`` shows
whether it was warm). ``--lookalikes`` weights the look-alike types in (``bench/synthetic_set.py``'s
weights: about half of the instances are then stains, seams, tyre marks ...), ``--library`` adds
``compose --library DIR``. ``--repeats N`` composes each count N times and prints the median; each row
notes ``others``, the CPU seconds other processes of the machine took meanwhile (from ``/proc/stat``),
and ``--wait-idle`` waits for idle CPUs before each run and runs again (up to 5 times) one during
which other processes took more than 3 CPU s. Issue #12 targets on a 2-core machine: 1,000 defects <= 10 s wall and
<= 1 GB peak; 10,000 defects <= 60 s.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TARGETS = {1000: (10.0, 1024.0), 10000: (60.0, None)}   # defects -> (wall s, peak MB)
IDLE_TRIES, OTHERS_MAX_CPU_S = 5, 3.0    # --wait-idle: a run during which others took more CPU is run again
PHASES = ("place", "props", "merge", "markings", "textures", "write", "validate", "preview", "preview_wait")


def busy_cpu_s() -> float:
    """CPU seconds the whole machine has been busy since boot (``/proc/stat``: all but idle and iowait)."""
    with open("/proc/stat") as fh:
        ticks = [int(x) for x in fh.readline().split()[1:9]]
    return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")


def wait_idle(busy_share: float = 0.1, window_s: float = 3.0, max_wait_s: float = 900.0) -> float:
    """Wait (at most ``max_wait_s``) until the CPUs were less than ``busy_share`` busy over
    ``window_s``: on a shared machine another job's work would be timed into ours. Seconds waited."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < max_wait_s:
        before = busy_cpu_s()
        time.sleep(window_s)
        if busy_cpu_s() - before < busy_share * window_s * os.cpu_count():
            break
    return time.perf_counter() - t0


def run_cli(layout: Path, count: int, out: Path, extra: list[str]) -> dict:
    """``roadtwin compose`` as a user runs it; wall time, peak RSS of its process tree, summary,
    and ``others_cpu_s``: what other processes of the machine took meanwhile (0 on a quiet machine)."""
    import psutil

    roadtwin = Path(sys.executable).with_name("roadtwin")
    cmd = [str(roadtwin), "compose", str(layout), "--defects", str(count), "-o", str(out), *extra]
    log = out.with_suffix(".log")
    busy0 = busy_cpu_s()
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT)
        ps, peak, peak_rss, tick = psutil.Process(proc.pid), 0, 0, 0
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)   # reap it ourselves: its own ru_maxrss
            if pid:
                break
            # PSS walks every page table (~3 ms a process): read every 0.2 s, or the sampling
            # itself takes most of a core from the command it measures; RSS is cheap.
            with_pss = tick % 10 == 0
            pss = rss = 0
            for p in [ps] + _children(ps):
                try:
                    rss += p.memory_info().rss
                    pss += p.memory_full_info().pss if with_pss else 0
                except psutil.Error:                           # ended between listing and reading
                    continue
            peak, peak_rss, tick = max(peak, pss), max(peak_rss, rss), tick + 1
            time.sleep(0.02)
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    result = {"wall_s": wall, "peak_mb": peak / 2**20, "rss_mb": max(peak_rss, usage.ru_maxrss * 1024) / 2**20,
              "ok": code == 0, "main_mb": usage.ru_maxrss / 1024.0,
              "cpu_s": usage.ru_utime + usage.ru_stime}   # the CLI and the helpers and workers it reaped
    result["others_cpu_s"] = max(0.0, busy_cpu_s() - busy0 - result["cpu_s"])
    if code:
        result["error"] = (log.read_text().strip().splitlines() or ["no output"])[-1]
        return result
    result["summary"] = json.loads((out / "summary.json").read_text())
    result["size_mb"] = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 2**20
    result["usd_bytes"] = sum(p.stat().st_size for p in out.rglob("*.usd[ac]") if p.is_file())
    return result


def _children(ps):
    import psutil

    try:
        return ps.children(recursive=True)
    except psutil.Error:
        return []


def _dense_copy(layout: Path) -> Path:
    from pxr import Sdf

    out = layout.with_name("town01_dense.usda")
    layer = Sdf.Layer.FindOrOpen(str(layout))
    root = layer.GetPrimAtPath(layer.defaultPrim and f"/{layer.defaultPrim}")
    for prop in list(root.properties):
        if prop.name.startswith("roadtwin:rules:weight:"):
            root.RemoveProperty(prop)
    for name, value in (("pothole", 4.0), ("crack", 2.0), ("manhole", 0.5)):
        attr = Sdf.AttributeSpec(root, f"roadtwin:rules:weight:{name}", Sdf.ValueTypeNames.Double)
        attr.default = value
        attr.custom = True
    root.properties["roadtwin:rules:spacingM"].default = 0.2
    layer.Export(str(out))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--map", type=Path, default=REPO / "tests" / "data" / "opendrive" / "Town01.xodr")
    ap.add_argument("--counts", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--executor", default=None)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=1, help="compose each count this many times (then the median)")
    ap.add_argument("--wait-idle", action="store_true",
                    help="before each run, wait until the CPUs are idle (a machine shared with other jobs)")
    ap.add_argument("--lookalikes", action="store_true", help="weight the look-alike types into the layout's rules")
    ap.add_argument("--library", type=Path, default=None, help="compose --library DIR (e.g. a photo library)")
    ap.add_argument("--preview-cost", type=int, default=0, metavar="PAIRS",
                    help="then compose the smallest count PAIRS times with and without --no-preview, "
                         "alternating, and print what the preview adds to the command's wall time")
    ap.add_argument("--props-cost", type=int, default=0, metavar="PAIRS",
                    help="then compose the smallest count PAIRS times with --props default and --props none, "
                         "alternating, and print what the props add (wall time, peak memory, USD bytes)")
    args = ap.parse_args()
    extra = [a for k, v in (("--executor", args.executor), ("--workers", args.workers), ("--library", args.library))
             if v is not None for a in (k, str(v))]
    roadtwin = Path(sys.executable).with_name("roadtwin")
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} (timings on a busy machine are not the targets' machine)")
    with tempfile.TemporaryDirectory(prefix="roadtwin-town-") as tmp:
        layout = Path(tmp) / "town01.usda"
        t0 = time.perf_counter()
        proc = subprocess.run([str(roadtwin), "import", "opendrive", str(args.map), "-o", str(layout)],
                              capture_output=True, text=True)
        import_s = time.perf_counter() - t0
        if proc.returncode:
            sys.exit(f"import failed: {proc.stderr.strip()}")
        print(f"map {args.map.name}: import {import_s:.2f} s ({proc.stdout.strip()})")
        if args.lookalikes:
            from synthetic_set import weighted_layout   # bench/: the script's folder is on sys.path

            layout = weighted_layout(layout, layout.with_name("town01_lookalikes.usda"), lookalikes=True)
            print(f"look-alike types weighted in: {layout.name}")
        head = (f"{'defects':>8} {'wall_s':>7} {'peak_MB':>8} {'rss_MB':>8} {'main_MB':>8} {'size_MB':>8} {'triangles':>9} "
                + " ".join(f"{p + '_s':>10}" for p in PHASES) + "  target")
        print(head)
        print("-" * len(head))
        dense = _dense_copy(layout)
        for n in args.counts:
            # Past the paper's 1,000 the default mix (speed bumps, 1-3 m depressions, 0.4 m spacing)
            # no longer fits Town01's ~22,800 m2 of lanes: the dense run uses potholes, cracks and
            # manholes at 0.2 m spacing.
            measure(n, layout if n <= 1000 else dense, Path(tmp), extra, args)
        if args.preview_cost:
            preview_cost(layout, min(args.counts), args.preview_cost, Path(tmp), extra)
        if args.props_cost:
            props_cost(layout, min(args.counts), args.props_cost, Path(tmp), extra)


def measure(n: int, layout: Path, tmp: Path, extra: list[str], args) -> None:
    """``args.repeats`` runs of ``n`` defects (see ``--wait-idle``), each a row, then their median."""
    runs = []
    for k in range(args.repeats):
        for attempt in range(IDLE_TRIES if args.wait_idle else 1):
            waited = wait_idle() if args.wait_idle else 0.0
            r = run_cli(layout, n, tmp / f"out{n}_{k}_{attempt}", extra)
            busy = args.wait_idle and r["others_cpu_s"] > OTHERS_MAX_CPU_S and attempt < IDLE_TRIES - 1
            print_row(n, r, f"  others {r['others_cpu_s']:.1f} cpu s, load {os.getloadavg()[0]:.1f}"
                      + (f", waited {waited:.0f} s for idle CPUs" if args.wait_idle else "")
                      + (": others were busy, not counted, again" if busy else ""))
            if not busy:
                break
        runs.append(r)
    if args.repeats > 1 and all(r.get("ok") for r in runs):
        import statistics

        med = {k: statistics.median(r[k] for r in runs) for k in ("wall_s", "peak_mb", "cpu_s")}
        walls = ", ".join(f"{r['wall_s']:.2f}" for r in runs)
        print(f"{'median':>8} {med['wall_s']:>7.2f} {med['peak_mb']:>8.0f}  of {len(runs)} runs "
              f"(wall {walls} s; cpu of the process tree {med['cpu_s']:.2f} s)")


def print_row(n: int, r: dict, note: str = "") -> None:
    """One table row: the figures of one run, its phase split and the verdict on the targets."""
    if not r.get("ok"):
        print(f"{n:>8} {r['wall_s']:>7.2f} {r['peak_mb']:>8.0f}  FAILED: {r['error']}")
        return
    s, t = r["summary"], r["summary"]["timings_s"]
    wall_t, mem_t = TARGETS.get(n, (None, None))
    verdict = []
    if wall_t:
        verdict.append(f"{'ok' if r['wall_s'] <= wall_t else 'MISS'} <= {wall_t:.0f} s")
    if mem_t:
        verdict.append(f"{'ok' if r['peak_mb'] <= mem_t else 'MISS'} <= {mem_t / 1024:.0f} GB")
    print(f"{n:>8} {r['wall_s']:>7.2f} {r['peak_mb']:>8.0f} {r['rss_mb']:>8.0f} {r['main_mb']:>8.0f} {r['size_mb']:>8.1f} "
          f"{s['triangles']:>9} " + " ".join(f"{t.get(p + '_s', float('nan')):>10.2f}" for p in PHASES)
          + "  " + ", ".join(verdict) + note)
    sys.stdout.flush()


def preview_cost(layout: Path, count: int, pairs: int, tmp: Path, extra: list[str]) -> None:
    """What ``preview.png`` adds to the command a user waits for: the plain compose against
    ``--no-preview``, alternated so that drift in the machine's state hits both alike (medians)."""
    import statistics

    walls = {"preview": [], "no preview": []}
    for k in range(pairs):
        for label, flags in (("preview", []), ("no preview", ["--no-preview"])):
            r = run_cli(layout, count, tmp / f"cost{k}{len(flags)}", extra + flags)
            if not r.get("ok"):
                sys.exit(f"compose failed: {r['error']}")
            walls[label].append(r["wall_s"])
    med = {k: statistics.median(v) for k, v in walls.items()}
    print(f"\npreview cost at {count} defects ({pairs} pairs): with {med['preview']:.2f} s "
          f"[{min(walls['preview']):.2f}-{max(walls['preview']):.2f}], --no-preview {med['no preview']:.2f} s "
          f"[{min(walls['no preview']):.2f}-{max(walls['no preview']):.2f}]: the preview adds "
          f"{med['preview'] - med['no preview']:.2f} s")


def props_cost(layout: Path, count: int, pairs: int, tmp: Path, extra: list[str]) -> None:
    """What the roadside world (``layers/props.usda``, on by default) adds: the plain compose
    (``--props default``) against ``--props none``, alternated (medians): wall time, peak memory
    (PSS of the process tree), the props' own phase (``props_s``: placement and terrain) and the
    stage's USD bytes (the same for every run of one setting: same seed, same bytes)."""
    import statistics

    runs: dict[str, list[dict]] = {"default": [], "none": []}
    for k in range(pairs):
        for label in ("none", "default"):
            r = run_cli(layout, count, tmp / f"props{k}{label}", extra + ["--props", label])
            if not r.get("ok"):
                sys.exit(f"compose failed: {r['error']}")
            runs[label].append(r)
            t = r["summary"]["timings_s"]
            print(f"  pair {k + 1} --props {label:<7}: wall {r['wall_s']:.2f} s, cpu {r['cpu_s']:.2f} s, "
                  f"peak {r['peak_mb']:.0f} MB, "
                  f"props_s {t.get('props_s', 0.0):.2f}, merge_s {t['merge_s']:.2f}, write_s {t['write_s']:.2f}, "
                  f"validate_s {t['validate_s']:.2f}, USD {r['usd_bytes']:,} B, all files {r['size_mb']:.1f} MB")
            sys.stdout.flush()

    def med(label, key):
        return statistics.median(r[key] for r in runs[label])

    def med_phases(label):      # the phases the props layer touches: written, then validated
        return statistics.median(r["summary"]["timings_s"]["write_s"] + r["summary"]["timings_s"]["validate_s"]
                                 for r in runs[label])
    with_, without = runs["default"][0], runs["none"][0]
    usd_a, usd_b = with_["usd_bytes"], without["usd_bytes"]
    print(f"\nprops cost at {count} defects ({pairs} pairs, medians): wall {med('default', 'wall_s'):.2f} s with, "
          f"{med('none', 'wall_s'):.2f} s without ({med('default', 'wall_s') - med('none', 'wall_s'):+.2f} s); "
          f"cpu {med('default', 'cpu_s'):.2f} s with, {med('none', 'cpu_s'):.2f} s without "
          f"({med('default', 'cpu_s') - med('none', 'cpu_s'):+.2f} s); "
          f"peak {med('default', 'peak_mb'):.0f} MB with, {med('none', 'peak_mb'):.0f} MB without; "
          f"props_s {statistics.median(r['summary']['timings_s']['props_s'] for r in runs['default']):.2f} s; "
          f"write + validate {med_phases('default'):.2f} s with, {med_phases('none'):.2f} s without; "
          f"{with_['summary']['props']['instances']} instances; USD {usd_a:,} B with, {usd_b:,} B without "
          f"({100.0 * (usd_a - usd_b) / usd_b:+.2f} %); all files {with_['size_mb']:.1f} MB with, "
          f"{without['size_mb']:.1f} MB without ({100.0 * (with_['size_mb'] - without['size_mb']) / without['size_mb']:+.2f} %)")


if __name__ == "__main__":
    main()
