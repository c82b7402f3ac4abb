#!/usr/bin/env python
"""Many worlds: compose several scenes and render survey frames of each, packed as one training set.

What issue 21 item 2 asks for: frames from >= 5 composed scenes (highway and town layouts,
seeds, road surfaces, props and defects from photos), in the survey rig, with every realism item
on (photo defect textures, look-alike types, props, measured camera targets). Each scene is a
copy of a sample layout with the look-alike types weighted in, composed with the photo library
(``--library``), then rendered with ``--rig survey --views defects:SHARE:clear --randomize
--classmap builtin:road_defects_br``; the frames of all scenes are packed (``bench/perception.py
pack``: JPEG + class-mapped PNG labels at 512x320) into one folder, names prefixed by the scene.

    .venv/bin/python bench/synthetic_set.py --library LIB [--road-textures MATS] --frames 1000 -o OUT [--device cuda] [--jobs N]
    # OUT/synthetic/{images,labels,classes.json}: what bench/perception.py --synthetic reads
    # OUT/synthetic/sources.json: the real frames whose pixels entered the set (photo defects
    # placed, photo road surfaces worn; bench/_synthetic_sources.py): the mixed arm's CV refuses
    # folds that hold them out

Prints per scene: compose seconds, render seconds and frames/s, pack seconds. Not a test.
``--scenes`` picks some; ``--no-photo`` (item 1, photo defects), ``--no-road-textures`` (item 2,
road surfaces from photos), ``--no-props`` (item 3), ``--no-lookalikes`` (item 4) and ``--no-camera``
(item 5, the measured camera targets: render with the class map minus its ``camera_targets``, so
``--randomize`` draws the generic camera) switch one realism item off for the ablation of issue 22.
``--photo-types pothole`` (or ``crack``) keeps only those photo defects (the rest parametric): which
photo defect type holds zero-shot back. ``--defect-priors builtin:road_defects_br --models-per-type 16
--defect-distance 2.5-12`` gives the frames the real train frames' defect geometry: pothole sizes
and distances measured from their labels (``bench/defect_priors.py``; the twin's frames held 0.11 %
pothole pixels against the real 1.22 %).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))       # bench/_synthetic_*.py, also when loaded by path
from _perception_data import SOURCES_FILE  # noqa: E402
from _synthetic_scene import (LOOKALIKE_WEIGHTS, asset_type, class_map, parse_weights, scene_library,  # noqa: E402,F401
                              views, weighted_layout)
from _synthetic_sources import scene_sources, set_sources, write_json  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Scene:
    name: str
    layout: str           # a sample layout under stages/
    seed: int
    defects: int
    surface: str | None = None      # compose --surface (None: the layout's)
    material: str | None = None     # render --material (a roadMaterial variant; None: the stage's)
    road_photo: int | None = None   # with --road-textures: the index of the photo surface the roads wear


# Dense defects (the real train labels hold 1.22 % pothole and 1.14 % crack pixels at 512x320,
# bench/label_stats.py; an earlier "0.27 % / 0.79 %" here were the shares of 8 val frames (the
# real-vs-synthetic figure's), not the train split's; docs/realism/ablation/README.md): the highway is ~2.5 km of two lanes.
SCENES = (
    Scene("highway_a", "stages/highway.usda", 11, 1200),
    Scene("highway_b", "stages/highway.usda", 12, 1500, surface="iso8608:C:0.2"),
    Scene("highway_c", "stages/highway.usda", 13, 1000, surface="iso8608:A:0.2"),
    Scene("highway_d", "stages/highway.usda", 14, 1200, surface="iso8608:B:0.2"),
    Scene("highway_e", "stages/highway.usda", 15, 1200, surface="iso8608:C:0.2"),
    Scene("town", "stages/town.usda", 5, 300, road_photo=2),
    Scene("town01", "stages/town01.usda", 7, 1500),
)
# Only one scene wears a photo road surface: repeated 2 m windows still show bands across the
# lane at their period (docs/realism/README.md), a pattern no real road has.


def run(cmd: list[str], log: Path) -> float:
    t0 = time.perf_counter()
    with log.open("a") as f:
        f.write("$ " + " ".join(cmd) + "\n")
        f.flush()
        done = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if done.returncode:
        sys.exit(f"{cmd[3]} failed (exit {done.returncode}); see {log}")
    return time.perf_counter() - t0


def make_scene(scene: Scene, args, out: Path, index: int) -> dict:
    """Compose (phase compose), render and pack (phase render) one scene; its timings."""
    work = out / "scenes" / scene.name
    row = {"scene": scene.name}
    if args.phase in ("compose", "all"):
        row["compose_s"] = compose_scene(scene, args, work, index)
    if args.phase in ("render", "all"):
        row.update(render_scene(scene, args, work, index))
    return row


def compose_scene(scene: Scene, args, work: Path, index: int) -> float:
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    log = work / "log.txt"
    cli = [sys.executable, "-m", "roadtwin_core.cli"]
    layout = weighted_layout(REPO / scene.layout, work / "layout.usda", not args.no_lookalikes,
                             parse_weights(args.weights), args.models_per_type)
    compose = [*cli, "compose", str(layout), "--defects", str(scene.defects), "--seed", str(scene.seed),
               "--props", "none" if args.no_props else "default", "--no-preview", "-o", str(work / "town")]
    if scene.surface:
        compose += ["--surface", scene.surface]
    if args.defect_priors:
        compose += ["--defect-priors", args.defect_priors]
    road = worn_road_textures(scene, args)
    if road:
        compose += ["--road-textures", str(road[0])]
        if scene.road_photo is not None and road[1]:
            compose += ["--road-material", road[1][0]]
    if args.library and not args.no_photo:
        lib = scene_library(args.library, work / "library", args.library_shares, index, args.photo_types)
        if lib is not None:
            compose += ["--library", str(lib)]
    seconds = run(compose, log)
    record_scene_sources(scene, args, work)
    return seconds


def worn_road_textures(scene: Scene, args) -> tuple[Path, list[str]] | None:
    """The --road-textures folder this scene composes with and the photo materials it wears
    (compose --road-material, render --material), or None without road textures."""
    if not args.road_textures or args.no_road_textures:
        return None
    names = [m["name"] for m in json.loads((args.road_textures / "materials.json").read_text())["materials"]]
    worn = [names[scene.road_photo % len(names)]] if scene.road_photo is not None and names else []
    return args.road_textures, worn + ([scene.material] if scene.material in names else [])


def record_scene_sources(scene: Scene, args, work: Path) -> Path:
    """``work/sources.json``: the real frames whose pixels this scene's town carries
    (bench/_synthetic_sources.py), read back from the composed town."""
    folder, worn = worn_road_textures(scene, args) or (None, [])
    return write_json(work / SOURCES_FILE, scene_sources(work / "town", folder, worn))


def render_scene(scene: Scene, args, work: Path, index: int) -> dict:
    log = work / "log.txt"
    cli = [sys.executable, "-m", "roadtwin_core.cli"]
    shutil.rmtree(work / "render", ignore_errors=True)
    shutil.rmtree(work / "packed", ignore_errors=True)
    if not (work / SOURCES_FILE).is_file() and (work / "town").is_dir():
        record_scene_sources(scene, args, work)    # composed before provenance was recorded
    render = [*cli, "render", str(work / "town" / "town.usda"), "--rig", "survey", "--views", views(args),
              "--randomize", "--classmap", class_map(args, work), "--frames", str(args.frames), "--size", args.size,
              "--seed", str(1000 + index), "--formats", "mmseg", "-o", str(work / "render")]
    if args.device:
        render += ["--device", args.device]
    if args.workers:
        render += ["--workers", str(args.workers)]
    if scene.material:
        render += ["--material", scene.material]
    t_render = run(render, log)
    t_pack = run([sys.executable, str(REPO / "bench/perception.py"), "pack", str(work / "render"), str(work / "packed"),
                  "--size", args.size], log)
    return {"render_s": t_render, "frames": args.frames, "frames_per_s": args.frames / t_render, "pack_s": t_pack}


def merge(out: Path, names: list[str]) -> int:
    """The packed scenes into one folder, file names prefixed by the scene (a scene rendered
    again replaces its own files; other scenes' files stay). Returns the folder's frame count."""
    dst = out / "synthetic"
    (dst / "images").mkdir(parents=True, exist_ok=True)
    (dst / "labels").mkdir(exist_ok=True)
    for name in names:
        for old in [*(dst / "images").glob(f"{name}_*"), *(dst / "labels").glob(f"{name}_*")]:
            old.unlink()
        packed = out / "scenes" / name / "packed"
        for img in sorted((packed / "images").iterdir()):
            shutil.move(str(img), dst / "images" / f"{name}_{img.name}")
            lab = packed / "labels" / f"{img.stem}.png"
            shutil.move(str(lab), dst / "labels" / f"{name}_{lab.name}")
        if (packed / "classes.json").is_file():
            shutil.copyfile(packed / "classes.json", dst / "classes.json")
    write_set_sources(out)
    return len(list((dst / "images").iterdir()))


def write_set_sources(out: Path, log=print) -> Path | None:
    """``OUT/synthetic/sources.json`` over every scene whose frames the set holds; none (and a
    stale one removed) when a scene's provenance was never recorded."""
    dst = out / "synthetic"
    names = {f.name for f in (dst / "images").iterdir()}
    present = [s.name for s in SCENES if any(n.startswith(f"{s.name}_") for n in names)]
    records = {}
    for name in present:
        path = out / "scenes" / name / SOURCES_FILE
        if not path.is_file():
            (dst / SOURCES_FILE).unlink(missing_ok=True)
            log(f"{dst / SOURCES_FILE}: not written: scene {name} has no {path.name} (compose it again)")
            return None
        records[name] = json.loads(path.read_text())
    return write_json(dst / SOURCES_FILE, set_sources(records))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--library", type=Path, help="photo defect library (roadtwin reconstruct photos)")
    ap.add_argument("--road-textures", type=Path, help="road materials from photos (roadtwin reconstruct photo-surfaces): "
                    "scenes with a road_photo wear one")
    ap.add_argument("--library-shares", type=int, default=5, help="scene i composes every N-th library asset (offset i)")
    ap.add_argument("--frames", type=int, default=1000, help="frames per scene")
    ap.add_argument("--size", default="512x320")
    ap.add_argument("--defect-share", type=float, default=0.8, help="share of views aimed at a defect (real survey frames were kept for their defects)")
    ap.add_argument("--device", default=None, help="render device (cpu | cuda)")
    ap.add_argument("--workers", type=int, default=None, help="render worker processes")
    ap.add_argument("--scenes", nargs="+", default=[s.name for s in SCENES], choices=[s.name for s in SCENES])
    ap.add_argument("--phase", choices=("compose", "render", "all"), default="all",
                    help="compose the scenes, render+pack them, or both (two GPU calls: each under the call limit)")
    ap.add_argument("--jobs", type=int, default=1, help="scenes at once (each compose/render is its own process)")
    ap.add_argument("--weights", help="defect-type weights of every scene's rules, e.g. pothole=2,crack=12 (to bring "
                    "the frames' pothole and crack pixel shares near the real train frames')")
    ap.add_argument("--defect-priors", help="compose --defect-priors (builtin:road_defects_br: pothole sizes measured "
                    "from the real train labels, bench/defect_priors.py)")
    ap.add_argument("--models-per-type", type=int, help="models a defect type per scene (default: the layout's)")
    ap.add_argument("--defect-distance", help="NEAR-FAR m: aimed defects this far ahead (render --views "
                    "defects:SHARE:clear:NEAR-FAR; the real train potholes lie 2.8-11.1 m ahead, 10th-90th percentile)")
    ap.add_argument("--label-range", help="CLASS=M,...: defect pixels deeper than M m unlabelled (ignore), as the "
                    "real annotators left them (bench/defect_priors.py: crack=8.5,pothole=15)")
    ap.add_argument("--no-lookalikes", action="store_true")
    ap.add_argument("--no-props", action="store_true")
    ap.add_argument("--no-photo", action="store_true")
    ap.add_argument("--photo-types", nargs="+", default=None, help="only these defect types from the photo library "
                    "(e.g. pothole: photo potholes, parametric cracks); default all")
    ap.add_argument("--no-road-textures", action="store_true")
    ap.add_argument("--no-camera", action="store_true")
    args = ap.parse_args()
    console = Console()
    args.out.mkdir(parents=True, exist_ok=True)
    chosen = [s for s in SCENES if s.name in args.scenes]
    t0 = time.perf_counter()
    with console.status(f"{len(chosen)} scenes, {args.jobs} at once, phase {args.phase}"), \
            ThreadPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(lambda sc: make_scene(sc, args, args.out, SCENES.index(sc)), chosen))
    wall = time.perf_counter() - t0
    record = args.out / "synthetic_set.json"
    old = json.loads(record.read_text()) if record.is_file() else {}
    by_scene = {r["scene"]: r for r in old.get("scenes", [])}
    for r in rows:
        by_scene[r["scene"]] = {**by_scene.get(r["scene"], {}), **r}
    summary = {"scenes": list(by_scene.values()), f"{args.phase}_wall_s": wall, **{k: v for k, v in old.items() if k.endswith("_wall_s")}}
    if args.phase in ("render", "all"):
        summary["frames"] = merge(args.out, [s.name for s in chosen])
    summary["args_" + args.phase] = {k: str(v) for k, v in vars(args).items()}
    record.write_text(json.dumps(summary, indent=1))
    table = Table(title=f"phase {args.phase}: {wall:.0f} s wall, {summary.get('frames', 0)} frames in {args.out / 'synthetic'}")
    for col in ("scene", "compose s", "render s", "frames/s", "pack s"):
        table.add_column(col, justify="right")
    fmt = lambda r, k, f: f.format(r[k]) if k in r else "-"  # noqa: E731
    for r in summary["scenes"]:
        table.add_row(r["scene"], fmt(r, "compose_s", "{:.1f}"), fmt(r, "render_s", "{:.1f}"),
                      fmt(r, "frames_per_s", "{:.2f}"), fmt(r, "pack_s", "{:.1f}"))
    console.print(table)


if __name__ == "__main__":
    main()
