"""Town01 with its roadside world (``layers/props.usda``), seen from three lanes: rendered frame
and semantic labels side by side, one row per view; writes ``docs/props_town01_views.png``.

    .venv/bin/python bench/props_figure.py                      # Town01, 300 defects, CPU ray caster
    .venv/bin/python bench/props_figure.py --layout stages/town.usda --figure /tmp/town.png

The layout (CARLA Town01 imported from tests/data/opendrive/Town01.xodr unless ``--layout``) is
composed with the default props, read back (``load_town``: instancers expanded) and rendered by
the warp renderer on the CPU. Views: three of the longest chained driving lanes, 30 % along
each, 2 m up, 4 degrees down, moved on past any vehicle standing in the lane (the rule the view
sampler keeps). The sun is low (28 degrees) so that poles, trees and cars throw long shadows on
the road. Label colours: road kinds grey-blue, defects warm, props green (vegetation), brown
(pole), yellow (sign), blue (vehicle), olive (terrain), silver (guardrail), tan (fence); pale pink
beyond the renderer's 150 m label distance (ignore: the distant hills).
Prints the composed town's props, the render mesh's triangle counts and each view's label share.
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
IGNORE_INDEX = 255

COLOURS = {  # label -> sRGB; anything else gets a seeded colour
    "background": (150, 190, 235), "driving": (110, 110, 140), "junction": (130, 120, 160),
    "sidewalk": (175, 175, 175), "shoulder": (150, 140, 120), "verge": (120, 150, 110),
    "lane_marking": (240, 240, 240), "pothole": (230, 60, 40), "crack": (250, 150, 30),
    "vegetation": (40, 160, 60), "pole": (120, 70, 30), "sign": (240, 210, 40), "vehicle": (40, 90, 230),
    "terrain": (140, 150, 80), "guardrail": (200, 200, 215), "fence": (200, 160, 110),
}


def palette(classes: list[str]) -> np.ndarray:
    rng = np.random.default_rng(3)
    out = rng.integers(60, 250, (256, 3)).astype(np.uint8)
    for i, name in enumerate(classes):
        if name in COLOURS:
            out[i] = COLOURS[name]
    out[IGNORE_INDEX] = (250, 215, 235)     # beyond the renderer's label distance (150 m): ignore
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layout", type=Path, default=None, help="a layout (default: Town01 imported from OpenDRIVE)")
    ap.add_argument("--map", type=Path, default=REPO / "tests" / "data" / "opendrive" / "Town01.xodr")
    ap.add_argument("--defects", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", default="640x400")
    ap.add_argument("--figure", type=Path, default=REPO / "docs" / "props_town01_views.png")
    args = ap.parse_args()

    from PIL import Image

    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.render import Camera, Intrinsics, RenderParams, build_render_mesh, lane_keep_out, look_from
    from roadtwin_core.render.scene import stage_lanes
    from roadtwin_core.render.view_sampler import chain_lanes
    from roadtwin_core.usd.town_reader import load_town
    from roadtwin_warp_render.renderer import WarpRenderer

    width, height = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory(prefix="roadtwin-props-") as tmp:
        layout = args.layout
        if layout is None:
            layout = Path(tmp) / "town01.usda"
            roadtwin = Path(sys.executable).with_name("roadtwin")
            subprocess.run([str(roadtwin), "import", "opendrive", str(args.map), "-o", str(layout)], check=True,
                           capture_output=True)
        result = compose(layout, Path(tmp) / "town", defects=args.defects, seed=args.seed, preview=False)
        print(f"props: {result.summary['props']['instances']} instances {result.summary['props']['by_rule']}")
        town = load_town(result.town, looks=True)
        mesh = build_render_mesh(town)
        n_props = sum(len(m.faces) for m in town.props)
        print(f"render mesh: {len(mesh.faces):,} triangles, {n_props:,} of them props; classes {mesh.classes}")
        keep = lane_keep_out(town)
        lanes = sorted(chain_lanes(stage_lanes(result.town)), key=lambda lane: -lane.length)
        cams = []
        for lane in lanes[:6:2]:
            s = 0.3 * lane.length
            while not keep.clear(lane.at(np.array([s]))[0]) and s + 1.0 < lane.length:
                s += 1.0
            p = lane.at(np.array([s]))[0]
            yaw = float(lane.heading(np.array([s]), window=2.0)[0])
            cams.append(Camera(Intrinsics.from_fov(width, height, 75.0), look_from([p[0], p[1], 2.0], yaw,
                                                                                   math.radians(-4.0))))
        params = RenderParams(sun_elevation_deg=28.0, sun_azimuth_deg=60.0, device="cpu")
        frames = list(WarpRenderer().render(mesh, cams, params))
    pal = palette(mesh.classes)
    rows = []
    for f in frames:
        rgb = (np.clip(f.rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
        rows.append(np.concatenate([rgb, pal[f.semantic]], axis=1))
        ids, counts = np.unique(f.semantic, return_counts=True)
        share = {mesh.classes[i] if i < len(mesh.classes) else "ignore": float(round(100.0 * c / f.semantic.size, 1))
                 for i, c in zip(ids, counts)}
        print("view label share %:", dict(sorted(share.items(), key=lambda kv: -kv[1])))
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, axis=0)).save(args.figure, optimize=True)
    print(f"wrote {args.figure} ({args.figure.stat().st_size / 1024:.0f} kB)")


if __name__ == "__main__":
    main()
