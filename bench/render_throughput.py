"""Dataset throughput of ``roadtwin render``, end to end, with seconds and frames/s per phase.

Runs the real render path (``apps.render.run_render``: stage read, view sampling, randomization,
ray casting and shading, the camera model, ego lane and class map, encoding and writing) with the
survey rig, ``--randomize`` and ``--classmap builtin:road_defects_br`` at 512x320 into a temporary
folder, after a short warm-up render (kernels compiled or loaded from warp's cache, imports
done), and prints per phase its seconds (summed over threads and worker processes), ms per frame
and the frames/s that phase alone allows on one thread; then the run's wall-clock frames/s::

    .venv/bin/python bench/render_throughput.py --frames 16 --device cpu          # here (2 cores)
    python3 bench/render_throughput.py --stage out/town.usda --frames 2000 --device cuda   # GPU

Phases: stage_read (USD -> render mesh), cameras (the camera source and the look table),
view_sampling (cameras and ego lanes, per frame), randomize (the per-frame draws), planning (the
wall seconds of those two: on forked processes from 1,024 frames, ``apps/render/planning.py``), prepare (scene to the device; once per process), render (ray
casting and shading, arrays to the host), sensor (blur, vignetting, exposure, noise, JPEG),
labels (ego lane, class map, dilation), write (PNG/JPEG/npy files, COCO masks), commit (meta
records, in order). On CUDA the warp renderer finishes frames on the device
(``apps/render/device_frames.py``): render then holds the camera model and the labels too (a
batch's seconds shared out over its frames), sensor only the JPEG encode/decode, labels only the
dilation. ``--formats`` (default ``mmseg``, what ``bench/perception.py`` reads).
Without ``--stage`` it composes ``stages/town.usda`` first (not timed).

``--executor ray``: a local Ray cluster is started once, before the warm-up, and both renders
use it, as renders on a running cluster do (its start is printed, not timed; ``--ray-address``
joins one). On CUDA each render still starts one fresh Ray worker per GPU (its own CUDA
context, ``apps/render/gpu_shards.py``), inside the frames phase; each shard's line says when its
card rendered, so the rate while the cards render shows beside the frames phase's.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SETUP = ("stage_read", "cameras", "view_sampling", "randomize", "planning", "prepare")
FRAME = ("render", "sensor", "labels", "write", "commit")


def options(args, frames: int, seed: int):
    from roadtwin_core.apps.render import RenderOptions

    return RenderOptions(frames=frames, rig="survey", size=args.size, views=args.views, randomize=True,
                         classmap="builtin:road_defects_br", formats=args.formats, seed=seed, device=args.device,
                         executor=args.executor, workers=args.workers)


def running_cluster(args) -> None:
    """Start (or join, ``--ray-address``) the Ray cluster the renders share; prints its start."""
    import ray

    t0 = time.perf_counter()
    ray.init(address=args.ray_address, num_cpus=None if args.ray_address else os.cpu_count(), include_dashboard=False,
             log_to_driver=False, logging_level="ERROR")
    print(f"ray cluster {'joined' if args.ray_address else 'started'} in {time.perf_counter() - t0:.1f} s "
          f"(not timed): {ray.cluster_resources()}")


def measure(stage: Path, args) -> dict:
    from roadtwin_core.apps.render import run_render

    if args.executor == "ray":
        running_cluster(args)
    with tempfile.TemporaryDirectory() as tmp:
        if args.warmup:
            run_render(stage, Path(tmp) / "warmup", options(args, args.warmup, args.seed + 1))
        t0 = time.perf_counter()
        t_start = time.time()
        summary = run_render(stage, Path(tmp) / "run", options(args, args.frames, args.seed))
        summary["t_start"] = t_start
        summary["wall_s"] = time.perf_counter() - t0
    return summary


def report(summary: dict) -> None:
    n = summary["frames"]
    phases = summary["phase_timings_s"]
    print(f"{summary['frames']} frames {summary['size'][0]}x{summary['size'][1]}, device {summary['device']}, "
          f"backend {summary['backend']}, executor {summary['executor']}, formats {','.join(summary['formats'])}")
    print(f"{'phase':>14} {'seconds':>9} {'ms/frame':>9} {'frames/s':>10}")
    for name in SETUP + FRAME + tuple(k for k in phases if k not in SETUP + FRAME):
        if name in phases:
            s = phases[name]
            print(f"{name:>14} {s:9.3f} {1e3 * s / n:9.2f} {n / max(s, 1e-9):10.1f}")
    t = summary["timings_s"]
    print(f"{'setup (wall)':>14} {t['setup']:9.3f}")
    print(f"{'frames (wall)':>14} {t['frames']:9.3f} {1e3 * t['frames'] / n:9.2f} {summary['frames_per_s']:10.1f}")
    wall = summary["wall_s"]
    print(f"{'end to end':>14} {wall:9.3f} {1e3 * wall / n:9.2f} {n / wall:10.1f}")
    for shard in summary.get("shards", []):        # --executor ray on GPUs: each card's frames and when it rendered them
        t0, t1 = shard.get("frames_from_to", (0.0, 0.0))
        print(f"shard gpu {shard.get('gpu')} card {shard.get('card')}: frames {shard['first']}..{shard['first'] + shard['frames'] - 1}"
              f" rendered in {t1 - t0:.2f} s ({shard['frames'] / max(t1 - t0, 1e-9):.1f} frames/s), from +{t0 - summary['t_start']:.2f} s"
              if "t_start" in summary else f"shard {shard}")
    spans = [s["frames_from_to"] for s in summary.get("shards", []) if "frames_from_to" in s]
    together = None
    if spans:
        span = max(b for _, b in spans) - min(a for a, _ in spans)
        together = round(n / max(span, 1e-9), 1)
        print(f"{'cards together':>14} {span:9.3f} {1e3 * span / n:9.2f} {together:10.1f}   (first frame of any card to last)")
    print("BENCH " + json.dumps({"frames": n, "device": summary["device"], "executor": summary["executor"],
                                 "cards_together_frames_per_s": together,
                                 "phases_s": phases, "frames_wall_s": t["frames"], "setup_wall_s": t["setup"],
                                 "frames_per_s": summary["frames_per_s"], "end_to_end_s": round(summary["wall_s"], 3),
                                 "end_to_end_frames_per_s": round(n / summary["wall_s"], 2)}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stage", type=Path, help="composed stage (default: compose stages/town.usda)")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--warmup", type=int, default=2, help="frames rendered first, untimed (0: none)")
    ap.add_argument("--size", default="512x320")
    ap.add_argument("--views", default="defects:0.6:clear")
    ap.add_argument("--formats", default="mmseg")
    ap.add_argument("--device", default=None, help="cpu | cuda | cuda:N (default: the renderer's)")
    ap.add_argument("--executor", default="local")
    ap.add_argument("--ray-address", default=None, help="--executor ray: join this cluster (default: start a local one)")
    ap.add_argument("--workers", type=int, default=None, help="threads on a GPU, processes on the CPU")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    stage = args.stage
    with tempfile.TemporaryDirectory() as tmp:
        if stage is None:
            from roadtwin_core.apps.compose.run import compose

            stage = compose(REPO / "stages/town.usda", Path(tmp) / "town", preview=False).town
        report(measure(stage, args))


if __name__ == "__main__":
    main()
