"""The same camera on a composed stage, rendered by roadtwin and by Blender, side by side.

Appearance is data in the stage (``layers/looks.usda``: UsdPreviewSurface materials, PNG
textures, ``primvars:st``; ``layers/markings.usda``: draped paint), so another tool must show
the same road, markings and potholes as roadtwin's own renderer. This script composes a layout,
picks the preview camera (the lane spot facing the most defects), renders it with roadtwin's
warp renderer, hands the stage and the camera to Blender (Cycles on the CPU, USD importer, no
roadtwin code inside Blender), and writes ``docs/looks_roadtwin_vs_blender.png``.

Blender runs as a Python module in its own venv (it needs CPython 3.11 and ~400 MB):

    python3 -m venv /tmp/bpy && /tmp/bpy/bin/pip install bpy
    .venv/bin/python bench/looks_figure.py --blender-python /tmp/bpy/bin/python

Options: ``--layout`` (default stages/defect_avoidance.usda), ``--out`` (scratch folder),
``--figure`` (default docs/looks_roadtwin_vs_blender.png), ``--samples`` (Cycles samples).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sun_vector(elevation_deg: float, azimuth_deg: float) -> list[float]:
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layout", default=str(ROOT / "stages/defect_avoidance.usda"))
    ap.add_argument("--out", default="/tmp/roadtwin_looks_figure")
    ap.add_argument("--figure", default=str(ROOT / "docs/looks_roadtwin_vs_blender.png"))
    ap.add_argument("--blender-python", default="/work/bpyvenv/bin/python",
                    help="a Python with the bpy module (Blender as a Python module)")
    ap.add_argument("--samples", type=int, default=48)
    args = ap.parse_args()

    from PIL import Image

    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.plugins import get_plugin_manager
    from roadtwin_core.apps.compose.preview import render_view
    from roadtwin_core.render import build_render_mesh
    from roadtwin_core.usd.town_reader import load_town

    out = Path(args.out)
    t0 = time.perf_counter()
    result = compose(args.layout, out / "town", preview=False, executor="serial")
    stage = result.town
    pm = get_plugin_manager()
    mesh = build_render_mesh(load_town(stage, looks=True))
    ours, note, spot, cam = render_view(stage, mesh, pm)
    if ours is None:
        sys.exit(f"roadtwin render failed: {note}")
    t1 = time.perf_counter()
    # The clear-sky preset's sun (raycast.LightSpec defaults: elevation 45, azimuth 135 deg).
    k = cam.intrinsics
    view = {"cam_to_world": np.asarray(cam.cam_to_world).tolist(), "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
            "width": k.width, "height": k.height, "sun_dir": sun_vector(45.0, 135.0), "sun_strength": 3.0,
            "sky_rgb": [0.55, 0.7, 0.95], "sky_strength": 0.6}
    (out / "view.json").write_text(json.dumps(view, indent=1))
    blender_png = out / "blender.png"
    run = subprocess.run([args.blender_python, str(ROOT / "bench/_blender_view.py"), str(stage), str(out / "view.json"),
                          str(blender_png), str(args.samples)], capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"Blender render failed:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}")
    blender_info = json.loads(run.stdout.strip().splitlines()[-1])
    t2 = time.perf_counter()

    theirs = np.asarray(Image.open(blender_png).convert("RGB"))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(16, 5.4))
    axes[0].imshow(ours)
    axes[0].set_title(f"roadtwin (warp ray caster): {Path(args.layout).name}, lane {spot.lane}", fontsize=10)
    axes[1].imshow(theirs)
    axes[1].set_title(f"Blender {blender_info.get('blender', '')} Cycles, USD import: {blender_info['meshes']} meshes, "
                      f"{len(blender_info['materials'])} materials", fontsize=10)
    for ax in axes:
        ax.set_axis_off()
    fig.tight_layout()
    Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.figure, dpi=90)
    print(f"wrote {args.figure}: compose + roadtwin render {t1 - t0:.1f} s, Blender {t2 - t1:.1f} s; "
          f"Blender materials: {', '.join(blender_info['materials'])}")


if __name__ == "__main__":
    main()
