"""Town01 with its roadside world (``layers/props.usda``), seen from three lanes: rendered frame
and semantic labels side by side, one row per view; writes ``docs/props_town01_views.png``.

    .venv/bin/python bench/props_figure.py                      # Town01, 300 defects, CPU ray caster
    .venv/bin/python bench/props_figure.py --layout stages/town.usda --figure /tmp/town.png
    .venv/bin/python bench/props_figure.py --blender-python /work/bpyenv/bin/python   # + Blender, two views

With ``--blender-python`` (a Python 3.11 venv with ``pip install bpy``: Blender as a module) two
views (``--blender-views``) are also rendered by Blender (Cycles on the CPU, ``--samples``) from
the composed stage's USD alone (bench/_blender_view.py), and written beside roadtwin's render of
the same cameras and sun: ``docs/realism/blender_props.png``, ``docs/realism/props_roadtwin_vs_blender.png``.

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
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
IGNORE_INDEX = 255
SUN_ELEVATION, SUN_AZIMUTH = 28.0, 60.0      # low: poles, trees and cars throw long shadows on the road

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


def lane_views(result, town, width: int, height: int) -> list:
    """Three of the longest chained driving lanes, 30 % along, 2 m up, 4 degrees down, moved on
    past any vehicle standing in the lane (the view sampler's rule)."""
    from roadtwin_core.render import Camera, Intrinsics, lane_keep_out, look_from
    from roadtwin_core.render.scene import stage_lanes
    from roadtwin_core.render.view_sampler import chain_lanes

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
    return cams


def sun_vector(elevation_deg: float, azimuth_deg: float) -> list[float]:
    """Unit vector towards the sun, world Z up, azimuth 0 = +X counter-clockwise (RenderParams)."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]


def blender_render(stage: Path, cams: list, args, tmp: Path) -> tuple[list[np.ndarray], dict]:
    """The same cameras and sun in Blender (Cycles, CPU; bench/_blender_view.py, USD import only)."""
    from PIL import Image

    views = []
    for cam in cams:
        k = cam.intrinsics
        views.append({"cam_to_world": np.asarray(cam.cam_to_world).tolist(), "fx": k.fx, "fy": k.fy, "cx": k.cx,
                      "cy": k.cy, "width": k.width, "height": k.height,
                      "sun_dir": sun_vector(SUN_ELEVATION, SUN_AZIMUTH), "sun_strength": 3.0,
                      "sky_rgb": [0.55, 0.7, 0.95], "sky_strength": 0.6})
    (tmp / "views.json").write_text(json.dumps(views))
    t0 = time.perf_counter()
    run = subprocess.run([str(args.blender_python), str(REPO / "bench" / "_blender_view.py"), str(stage),
                          str(tmp / "views.json"), str(tmp / "blender.png"), str(args.samples)],
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"Blender render failed:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}")
    info = json.loads(run.stdout.strip().splitlines()[-1])
    info["seconds"] = round(time.perf_counter() - t0, 1)
    return [np.asarray(Image.open(tmp / f"blender-{k}.png").convert("RGB")) for k in range(len(cams))], info


def save_blender_figures(ours: list[np.ndarray], theirs: list[np.ndarray], info: dict, args) -> None:
    """blender_props.png: Blender's views one under the other; the pair figure: roadtwin | Blender."""
    from PIL import Image, ImageDraw

    args.blender_figure.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(theirs, axis=0)).save(args.blender_png, optimize=True)
    pair = Image.fromarray(np.concatenate([np.concatenate([a, np.full((a.shape[0], 8, 3), 255, np.uint8), b], axis=1) for a, b in zip(ours, theirs)]))
    head = Image.new("RGB", (pair.width, 24), "white")
    draw = ImageDraw.Draw(head)
    draw.text((8, 6), "roadtwin (warp ray caster, CPU)", fill="black")
    draw.text((ours[0].shape[1] + 16, 6), f"Blender {info['blender']} Cycles ({args.samples} samples), USD import: "
              f"{info['meshes']} meshes, {len(info['instancers'])} point instancers", fill="black")
    both = Image.new("RGB", (pair.width, pair.height + head.height), "white")
    both.paste(head, (0, 0))
    both.paste(pair, (0, head.height))
    both.save(args.blender_figure, optimize=True)
    print(f"Blender {info['blender']}: {info['seconds']} s for {len(theirs)} views, instancers {info['instancers']}")
    print(f"wrote {args.blender_png} and {args.blender_figure}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layout", type=Path, default=None, help="a layout (default: Town01 imported from OpenDRIVE)")
    ap.add_argument("--map", type=Path, default=REPO / "tests" / "data" / "opendrive" / "Town01.xodr")
    ap.add_argument("--defects", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", default="640x400")
    ap.add_argument("--figure", type=Path, default=REPO / "docs" / "props_town01_views.png")
    ap.add_argument("--out", type=Path, default=None, help="keep the composed town here (default: a temp dir)")
    ap.add_argument("--blender-python", type=Path, default=None,
                    help="a Python with bpy: also render one view in Blender (Cycles, CPU)")
    ap.add_argument("--blender-views", default="0,2",
                    help="views Blender renders (0: trees, a guardrail; 2: a truck, a sign, poles with wires)")
    ap.add_argument("--samples", type=int, default=32, help="Cycles samples per pixel")
    ap.add_argument("--blender-png", type=Path, default=REPO / "docs" / "realism" / "blender_props.png")
    ap.add_argument("--blender-figure", type=Path,
                    default=REPO / "docs" / "realism" / "props_roadtwin_vs_blender.png")
    args = ap.parse_args()

    from PIL import Image

    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.render import RenderParams, build_render_mesh
    from roadtwin_core.usd.town_reader import load_town
    from roadtwin_warp_render.renderer import WarpRenderer

    width, height = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory(prefix="roadtwin-props-") as tmp:
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            tmp = args.out
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
        cams = lane_views(result, town, width, height)
        params = RenderParams(sun_elevation_deg=SUN_ELEVATION, sun_azimuth_deg=SUN_AZIMUTH, device="cpu")
        frames = list(WarpRenderer().render(mesh, cams, params))
        if args.blender_python is not None:
            views = [int(v) for v in args.blender_views.split(",")]
            theirs, info = blender_render(result.town, [cams[v] for v in views], args, Path(tmp))
    pal = palette(mesh.classes)
    rows = []
    for f in frames:
        rgb = srgb(f.rgb)
        rows.append(np.concatenate([rgb, pal[f.semantic]], axis=1))
        ids, counts = np.unique(f.semantic, return_counts=True)
        share = {mesh.classes[i] if i < len(mesh.classes) else "ignore": float(round(100.0 * c / f.semantic.size, 1))
                 for i, c in zip(ids, counts)}
        print("view label share %:", dict(sorted(share.items(), key=lambda kv: -kv[1])))
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, axis=0)).save(args.figure, optimize=True)
    print(f"wrote {args.figure} ({args.figure.stat().st_size / 1024:.0f} kB)")
    if args.blender_python is not None:
        save_blender_figures([srgb(frames[v].rgb) for v in views], theirs, info, args)


def srgb(rgb: np.ndarray) -> np.ndarray:
    return (np.clip(rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)


if __name__ == "__main__":
    main()
