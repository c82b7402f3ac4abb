"""Fingerprint what the main commands write, to show a refactor changed no output byte.

Runs ``compose`` (sample town; CARLA Town01 with 1,000 defects), ``render`` (every dataset format,
stereo and events; the survey rig with randomization and a class map), ``plan --all`` and
``sweep`` (warp and pybullet) into OUT, then writes ``OUT/manifest.json``: sha256 of every file.
Run it on two checkouts and compare the manifests::

    .venv/bin/python bench/same_outputs.py /tmp/after
    PYTHONPATH=../base:../base/plugins .venv/bin/python bench/same_outputs.py /tmp/before
    .venv/bin/python bench/same_outputs.py --compare /tmp/before /tmp/after

What is measured while running (timings, wall-clock fields) is not an output: JSON keys and CSV
columns whose name says time (``time``, ``timings``, ``elapsed``, ``_s`` of a duration) are
dropped before hashing; everything else, images and USD crates included, is hashed as written.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TIMING_KEYS = ("time", "timing", "elapsed", "wall", "duration", "per_frame", "fps", "frames_per_s")


def commands(out: Path) -> list[list[str]]:
    town, t01 = out / "town", out / "town01"
    return [
        ["compose", str(REPO / "stages/town.usda"), "-o", str(town)],
        ["compose", str(REPO / "stages/town01.usda"), "--defects", "1000", "-o", str(t01)],
        ["render", str(town / "town.usda"), "-o", str(out / "render"), "--frames", "3", "--size", "160x96",
         "--stereo", "--events", "--event-frames", "6", "--formats", "kitti,mmseg,coco,depth,normal",
         "--executor", "serial"],
        ["render", str(town / "town.usda"), "-o", str(out / "survey"), "--frames", "3", "--rig", "survey",
         "--size", "256x160", "--views", "defects:0.6", "--randomize", "--classmap", "builtin:road_defects_br",
         "--executor", "serial"],
        ["plan", str(REPO / "stages/defect_avoidance.usda"), "--all", "-o", str(out / "plan")],
        ["sweep", str(town / "town.usda"), "--backend", "warp", "--speeds", "10,30", "-o", str(out / "sweep_warp")],
        ["sweep", str(town / "town.usda"), "--backend", "pybullet", "--speeds", "10,30", "-o",
         str(out / "sweep_pybullet")],
    ]


def _is_timing(name: str) -> bool:
    n = name.lower()
    return any(k in n for k in TIMING_KEYS)


def _strip(value):
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if not _is_timing(k)}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


def fingerprint(path: Path, out: Path) -> str:
    """sha256 of a file; JSON and CSV with timings dropped and the output folder's and the checkout's paths as ``<OUT>`` and ``<REPO>``."""
    data = path.read_bytes()
    if path.suffix in (".json", ".csv"):
        data = data.replace(str(out).encode(), b"<OUT>").replace(str(REPO).encode(), b"<REPO>")
    if path.suffix == ".json":
        data = json.dumps(_strip(json.loads(data)), sort_keys=True).encode()
    elif path.suffix == ".csv":
        rows = list(csv.reader(io.StringIO(data.decode())))
        if rows:
            keep = [i for i, h in enumerate(rows[0]) if not _is_timing(h)]
            data = "\n".join(",".join(r[i] for i in keep if i < len(r)) for r in rows).encode()
    return hashlib.sha256(data).hexdigest()


def run(out: Path, rehash: bool = False) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for args in [] if rehash else commands(out):
        print("roadtwin", " ".join(args), flush=True)
        subprocess.run([sys.executable, "-c", "from roadtwin_core.cli import main; main()", *args], check=True,
                       stdout=subprocess.DEVNULL)
    manifest = {p.relative_to(out).as_posix(): fingerprint(p, out) for p in sorted(out.rglob("*"))
                if p.is_file() and p.name != "manifest.json"}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True))
    print(f"{len(manifest)} files fingerprinted -> {out / 'manifest.json'}")


def compare(a: Path, b: Path) -> int:
    ma, mb = (json.loads((d / "manifest.json").read_text()) for d in (a, b))
    only_a, only_b = sorted(ma.keys() - mb.keys()), sorted(mb.keys() - ma.keys())
    differ = sorted(k for k in ma.keys() & mb.keys() if ma[k] != mb[k])
    for label, names in (("only in " + str(a), only_a), ("only in " + str(b), only_b), ("differ", differ)):
        for n in names:
            print(f"{label}: {n}")
    same = len(ma.keys() & mb.keys()) - len(differ)
    print(f"{same} files identical, {len(differ)} differ, {len(only_a) + len(only_b)} missing on one side")
    return 1 if differ or only_a or only_b else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, nargs="+", help="output folder (or two with --compare)")
    ap.add_argument("--compare", action="store_true", help="compare the manifests of two output folders")
    ap.add_argument("--rehash", action="store_true", help="only fingerprint an existing output folder again")
    a = ap.parse_args()
    if a.compare:
        sys.exit(compare(*a.out))
    run(a.out[0], a.rehash)


if __name__ == "__main__":
    main()
