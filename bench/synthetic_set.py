#!/usr/bin/env python
"""Many worlds: compose several scenes and render survey frames of each, packed as one training set.

What issue 21 item 2 asks for: frames from >= 5 composed scenes (highway and town layouts,
seeds, road surfaces, props and defects from photos), in the survey rig, with every realism item
on (photo defect textures, look-alike types, props, measured camera targets). Each scene is a
copy of a sample layout with the look-alike types weighted in, composed with the photo library
(``--library``), then rendered with ``--rig survey --views defects:SHARE:clear --randomize
--classmap builtin:road_defects_br``; the frames of all scenes are packed (``bench/perception.py
pack``: JPEG + class-mapped PNG labels at 512x320) into one folder, names prefixed by the scene.

    .venv/bin/python bench/synthetic_set.py --library LIB --frames 1000 -o OUT [--device cuda]
    # OUT/synthetic/{images,labels,classes.json}: what bench/perception.py --synthetic reads

Prints per scene: compose seconds, render seconds and frames/s, pack seconds. Not a test.
``--scenes`` picks some; ``--no-lookalikes`` / ``--no-props`` / ``--no-photo`` switch a realism
item off for an ablation (issue 22: each item off in turn).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from pxr import Sdf
from rich.console import Console
from rich.table import Table

REPO = Path(__file__).resolve().parents[1]
# Look-alikes beside the defects, per unit of the layout's own pothole weight 5 (the highway's):
# the stains, sealed cracks, tyre marks and seams a Brazilian survey frame shows.
LOOKALIKE_WEIGHTS = {"oil_stain": 1.0, "tar_stain": 1.0, "sealed_crack": 1.5, "tyre_mark": 1.0, "wet_patch": 0.5,
                     "puddle": 0.5, "debris": 0.5, "patch_seam": 1.0, "worn_paint": 0.5, "ghost_paint": 0.5}


@dataclass(frozen=True)
class Scene:
    name: str
    layout: str           # a sample layout under stages/
    seed: int
    defects: int
    surface: str | None = None      # compose --surface (None: the layout's)
    material: str | None = None     # render --material (a roadMaterial variant; None: the stage's)


SCENES = (
    Scene("highway_a", "stages/highway.usda", 11, 400),
    Scene("highway_b", "stages/highway.usda", 12, 600, surface="iso8608:C:0.2"),
    Scene("highway_c", "stages/highway.usda", 13, 300, surface="iso8608:A:0.2"),
    Scene("town", "stages/town.usda", 5, 150),
    Scene("town01", "stages/town01.usda", 7, 800),
)


def weighted_layout(src: Path, dst: Path, lookalikes: bool) -> Path:
    """A copy of ``src`` whose compose rules weight the look-alike types in."""
    layer = Sdf.Layer.FindOrOpen(str(src))
    out = Sdf.Layer.CreateNew(str(dst))
    out.TransferContent(layer)
    root = out.GetPrimAtPath(out.defaultPrim and f"/{out.defaultPrim}" or out.rootPrims[0].path)
    if lookalikes:
        for kind, w in LOOKALIKE_WEIGHTS.items():
            Sdf.AttributeSpec(root, f"roadtwin:rules:weight:{kind}", Sdf.ValueTypeNames.Double,
                              Sdf.VariabilityVarying, True).default = w
    out.Save()
    return dst


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
    work = out / "scenes" / scene.name
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    log = work / "log.txt"
    cli = [sys.executable, "-m", "roadtwin_core.cli"]
    layout = weighted_layout(REPO / scene.layout, work / "layout.usda", not args.no_lookalikes)
    compose = [*cli, "compose", str(layout), "--defects", str(scene.defects), "--seed", str(scene.seed),
               "--props", "none" if args.no_props else "default", "--no-preview", "-o", str(work / "town")]
    if scene.surface:
        compose += ["--surface", scene.surface]
    if args.library and not args.no_photo:
        compose += ["--library", str(args.library)]
    t_compose = run(compose, log)
    render = [*cli, "render", str(work / "town" / "town.usda"), "--rig", "survey", "--views", f"defects:{args.defect_share}:clear",
              "--randomize", "--classmap", "builtin:road_defects_br", "--frames", str(args.frames), "--size", args.size,
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
    return {"scene": scene.name, "compose_s": t_compose, "render_s": t_render, "frames": args.frames,
            "frames_per_s": args.frames / t_render, "pack_s": t_pack}


def merge(out: Path, names: list[str]) -> int:
    """The packed scenes as one folder, file names prefixed by the scene."""
    dst = out / "synthetic"
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "images").mkdir(parents=True)
    (dst / "labels").mkdir()
    count = 0
    for name in names:
        packed = out / "scenes" / name / "packed"
        for img in sorted((packed / "images").iterdir()):
            shutil.move(str(img), dst / "images" / f"{name}_{img.name}")
            lab = packed / "labels" / f"{img.stem}.png"
            shutil.move(str(lab), dst / "labels" / f"{name}_{lab.name}")
            count += 1
        if (packed / "classes.json").is_file():
            shutil.copyfile(packed / "classes.json", dst / "classes.json")
    return count


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--library", type=Path, help="photo defect library (roadtwin reconstruct photos)")
    ap.add_argument("--frames", type=int, default=1000, help="frames per scene")
    ap.add_argument("--size", default="512x320")
    ap.add_argument("--defect-share", type=float, default=0.5, help="share of views aimed at a defect")
    ap.add_argument("--device", default=None, help="render device (cpu | cuda)")
    ap.add_argument("--workers", type=int, default=None, help="render worker processes")
    ap.add_argument("--scenes", nargs="+", default=[s.name for s in SCENES], choices=[s.name for s in SCENES])
    ap.add_argument("--no-lookalikes", action="store_true")
    ap.add_argument("--no-props", action="store_true")
    ap.add_argument("--no-photo", action="store_true")
    args = ap.parse_args()
    console = Console()
    args.out.mkdir(parents=True, exist_ok=True)
    chosen = [s for s in SCENES if s.name in args.scenes]
    rows = []
    with console.status("") as status:
        for i, scene in enumerate(chosen):
            status.update(f"scene {i + 1}/{len(chosen)}: {scene.name}")
            rows.append(make_scene(scene, args, args.out, SCENES.index(scene)))
            console.print(f"{scene.name}: compose {rows[-1]['compose_s']:.0f} s, render {rows[-1]['render_s']:.0f} s "
                          f"({rows[-1]['frames_per_s']:.1f} frames/s)")
    total = merge(args.out, [s.name for s in chosen])
    (args.out / "synthetic_set.json").write_text(json.dumps({"scenes": rows, "frames": total, "args": {
        k: str(v) for k, v in vars(args).items()}}, indent=1))
    table = Table(title=f"{total} frames in {args.out / 'synthetic'}")
    for col in ("scene", "compose s", "render s", "frames/s", "pack s"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(r["scene"], f"{r['compose_s']:.1f}", f"{r['render_s']:.1f}", f"{r['frames_per_s']:.2f}", f"{r['pack_s']:.1f}")
    console.print(table)


if __name__ == "__main__":
    main()
