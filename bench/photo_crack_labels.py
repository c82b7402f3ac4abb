#!/usr/bin/env python
"""How wide, and how visible, are the crack labels of frames made with photo-made crack assets?
(issue 22: a model trained on photo-library frames scored crack IoU 5 on real val, on parametric
ones 17; their crack labels were twice as wide as the real strokes, then, as strokes, nearly
invisible in RGB: the renderer's MIP levels mixed them with the road colour beside them.)

    .venv/bin/python bench/photo_crack_labels.py --photos-every 60 --frames 24      # ~5 min on 2 busy CPU cores

Three arms, each composed from ``stages/highway.usda`` (defect types crack and pothole only,
``--defects``, props none, seed ``--seed``) and rendered on the CPU (survey rig, ``--views
defects:0.5``, 512x320, ``--classmap builtin:road_defects_br``):

- ``strokes``: a photo library (every ``--photos-every``-th ``train_full`` frame, train only) made
  as now: a crack asset's mesh, and so its label, is the label's strokes, its albedo their dark
  core, edge-padded (plugins/roadtwin_photo/strokes.py);
- ``area``: the same photos with ``--param crack_strokes=false`` (before: the closed strokes'
  area, holes filled, plus the fade band);
- ``parametric``: no library.

The library arms draw 1 parametric model per type beside the photo ones (``models_per_type``), so
almost every crack is photo-made. ``--randomize`` renders with the per-frame camera model and
looks, as bench/synthetic_set.py's training frames are. Prints per arm: crack assets (mesh area /
label area), frames with a crack, crack pixel share, median 2A/P of the per-frame crack masks
(bench/label_stats.py's measure), and the median Weber contrast of crack and pothole instances
to the road around them (bench/label_contrast.py's measure: is the labelled defect visible?),
against the real ``train`` frames. Writes to ``--figure`` each arm's frame with the most crack
pixels beside a zoom of its crack, RGB and labels. ``--out DIR --reuse`` keeps what DIR holds. Not a test.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from label_contrast import folder_contrasts, instance_contrasts  # noqa: E402
from label_stats import stroke_width  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "road_defects_br"
CRACK, MIN_PIXELS = 2, 20                     # road_defects_br's crack id; label_stats.py's frame threshold


def run(*args: str, reuse: bool = False) -> None:
    """One roadtwin command (its output, after ``-o``, kept when ``reuse`` and it exists)."""
    if reuse and Path(args[args.index("-o") + 1]).exists():
        return
    print("roadtwin", " ".join(args), flush=True)
    subprocess.run([str(Path(sys.executable).with_name("roadtwin")), *args], check=True, stdout=subprocess.DEVNULL)


def make_arm(out: Path, name: str, library: Path | None, args) -> Path:
    from roadtwin_core.usd import read_layout, write_layout

    layout = read_layout(REPO / "stages" / "highway.usda")
    layout.rules.type_weights = {"crack": 2.0, "pothole": 1.0}
    if library is not None:
        layout.rules.models_per_type = 1
    write_layout(layout, out / f"{name}.usda")
    run("compose", str(out / f"{name}.usda"), "--defects", str(args.defects), "--seed", str(args.seed), "--props",
        "none", "--no-preview", *(["--library", str(library)] if library else []), "-o", str(out / f"{name}_town"),
        reuse=args.reuse)
    run("render", str(out / f"{name}_town" / "town.usda"), "--rig", "survey", "--views", "defects:0.5",
        "--classmap", "builtin:road_defects_br", "--frames", str(args.frames), "--size", "512x320", "--formats",
        "mmseg", "--seed", str(args.seed), "--executor", "serial", *(["--randomize"] if args.randomize else []),
        "-o", str(out / f"{name}_render{'_randomized' if args.randomize else ''}"), reuse=args.reuse)
    return out / f"{name}_render{'_randomized' if args.randomize else ''}"


def frames_of(render: Path) -> list[tuple[str, Path, np.ndarray, np.ndarray]]:
    """(stem, rgb path, crack mask, pothole mask) of each frame."""
    meta = json.loads((render / "meta.json").read_text())
    ids = {c["name"]: c["id"] for c in meta["classes"]}
    labels = [(fr, cv2.imread(str(render / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)) for fr in meta["frames"]]
    return [(fr["stem"], render / fr["files"]["rgb"], lab == ids["crack"], lab == ids["pothole"]) for fr, lab in labels]


def crack_stats(masks: list[np.ndarray]) -> dict:
    widths = [stroke_width(m) for m in masks if m.sum() >= MIN_PIXELS]
    return {"frames": len(masks), "crack_frames": len(widths),
            "share_pct": 100.0 * float(np.mean([m.mean() for m in masks])),
            "width_px": float(np.median(widths)) if widths else float("nan")}


def library_stats(lib: Path) -> str:
    meta = json.loads((lib / "instances.json").read_text())
    cracks = [a for a in meta["assets"] if a["type"] == "crack"]
    mesh = sum(float(a.get("areaM2", a.get("area_m2", 0.0))) for a in cracks)
    label = sum(a["footprint_area_m2"] for a in cracks)
    skipped = [s["why"].split(" (")[0] for s in meta["skipped"] if s["class"] == "crack"]
    why = {w: skipped.count(w) for w in sorted(set(skipped))}
    return (f"{len(cracks)} crack assets, {len(meta['assets']) - len(cracks)} others; crack label area "
            f"{label:.2f} m2, mesh {mesh:.2f} m2 (x{mesh / max(label, 1e-9):.2f}); crack instances skipped: {why}")


def overlay(rgb: np.ndarray, crack: np.ndarray) -> np.ndarray:
    out = rgb.copy()
    out[crack] = (0.35 * out[crack] + 0.65 * np.array([0, 0, 255])).astype(np.uint8)
    return out


def panel_row(title: str, frame, zoom: int = 3) -> np.ndarray:
    """The frame (crack box in red) | that box zoomed: RGB | crack labels tinted red; a title bar
    with the median Weber contrast C of the frame's crack instances (bench/label_contrast.py)."""
    stem, rgb_path, crack, pothole = frame
    rgb = cv2.imread(str(rgb_path))
    label = np.where(crack, CRACK, np.where(pothole, CRACK + 1, 1)).astype(np.uint8)
    contrast = instance_contrasts(cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB), label, CRACK, (CRACK, CRACK + 1))
    c = f"{np.median([v[0] for v in contrast]):.3f}" if contrast else "-"
    h, w = crack.shape
    ch, cw = h // zoom, w // zoom
    ys, xs = np.nonzero(crack) if crack.any() else (np.array([h // 2]), np.array([w // 2]))
    cy, cx = int(np.median(ys)), int(np.median(xs))
    y0, x0 = min(max(cy - ch // 2, 0), h - ch), min(max(cx - cw // 2, 0), w - cw)
    crop = (slice(y0, y0 + ch), slice(x0, x0 + cw))
    big = lambda im: cv2.resize(im[crop], (w, h), interpolation=cv2.INTER_NEAREST)   # noqa: E731
    full = rgb.copy()
    cv2.rectangle(full, (x0, y0), (x0 + cw - 1, y0 + ch - 1), (0, 0, 255), 1)
    row = np.concatenate([full, big(rgb), big(overlay(rgb, crack))], axis=1)
    bar = np.full((26, row.shape[1], 3), 255, np.uint8)
    text = (f"{title}: frame {stem}, {int(crack.sum())} crack px, 2A/P {stroke_width(crack):.2f} px, contrast C {c}; "
            f"right: the red box x{zoom}, RGB | crack labels in red")
    cv2.putText(bar, text, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([bar, row], axis=0)


def asset_view(lib: Path, name: str, size: int, mesh_only: bool = False) -> np.ndarray:
    """An asset's diffuse texture (over grey where transparent; with ``mesh_only`` grey outside
    its mesh too: what a renderer shows) with its mesh outline, the area the renderer labels, in red."""
    from roadtwin_core.usd import read_defect_asset

    model = read_defect_asset(lib / f"{name}.usda")
    rgba = cv2.imread(model.look.textures["diffuse"], cv2.IMREAD_UNCHANGED).astype(float)
    a = rgba[..., 3:] / 255.0
    img = (rgba[..., :3] * a + 128 * (1 - a)).astype(np.uint8)
    scale = size / max(img.shape[:2])
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    st = model.look.st(model.vertices[model.boundary, :2])
    px = np.column_stack([st[:, 0] * img.shape[1], (1 - st[:, 1]) * img.shape[0]])
    if mesh_only:
        inside = np.zeros(img.shape[:2], np.uint8)
        cv2.fillPoly(inside, [np.round(px * 8).astype(np.int32)], 1, cv2.LINE_8, shift=3)
        img[inside == 0] = 128
    cv2.polylines(img, [np.round(px * 8).astype(np.int32)], True, (0, 0, 255), 1, cv2.LINE_AA, shift=3)
    canvas = np.full((size, size, 3), 255, np.uint8)
    canvas[:img.shape[0], :img.shape[1]] = img
    return canvas


def asset_row(out: Path, size: int = 512) -> tuple[np.ndarray, str]:
    """The photo crack with the largest stroke area that both libraries hold (same frame, same box)."""
    metas = {lib: json.loads((out / lib / "instances.json").read_text())["assets"] for lib in ("lib_area", "lib_strokes")}
    key = lambda a: (a["image"], tuple(a["bbox_px"]))                      # noqa: E731
    area = {key(a): a for a in metas["lib_area"] if a["type"] == "crack"}
    both = [a for a in metas["lib_strokes"] if a["type"] == "crack" and key(a) in area]
    after = max(both, key=lambda a: a["footprint_area_m2"])
    before = area[key(after)]
    row = np.concatenate([asset_view(out / "lib_area", before["name"], size),
                          asset_view(out / "lib_strokes", after["name"], size, mesh_only=True),
                          asset_view(out / "lib_strokes", after["name"], size)], axis=1)
    bar = np.full((26, row.shape[1], 3), 255, np.uint8)
    text = (f"asset {after['name']}, labelled mesh outline in red: left the photo's texture and crack area "
            f"(mesh {before['areaM2']:.3f} m2); middle the strokes' mesh (mesh {after['areaM2']:.3f} m2, strokes "
            f"{after['footprint_area_m2']:.3f} m2) with its dark-core colour; right its whole edge-padded texture")
    cv2.putText(bar, text, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([bar, row], axis=0), after["name"]


def figure(arms: dict[str, list], path_out: Path, path: Path) -> str:
    """Per arm, its frame with the most crack pixels (placements differ between the arms: their
    libraries hold other crack assets)."""
    rows, stems = [], []
    for title, name in (("photo crack areas (crack_strokes=false)", "area"),
                        ("photo crack strokes (dark core, edge-padded)", "strokes"), ("parametric cracks only", "parametric")):
        frame = max(arms[name], key=lambda f: int(f[2].sum()))
        rows.append(panel_row(title, frame))
        stems.append(f"{name} {frame[0]}")
    assets, name = asset_row(path_out)
    rows.append(np.pad(assets, ((0, 0), (0, rows[0].shape[1] - assets.shape[1]), (0, 0)), constant_values=255))
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate(rows, axis=0), [cv2.IMWRITE_JPEG_QUALITY, 88])
    return ", ".join(stems) + f"; asset {name}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photos-every", type=int, default=60, help="every N-th train_full frame is reconstructed")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--defects", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="scratch folder (default: a temp dir)")
    ap.add_argument("--reuse", action="store_true", help="with --out: keep the libraries, towns and renders it holds")
    ap.add_argument("--randomize", action="store_true", help="render with --randomize (the training frames' looks)")
    ap.add_argument("--figure", type=Path, default=REPO / "docs" / "realism" / "photo_crack_labels.jpg")
    args = ap.parse_args()
    if not (REAL / "train_full" / "images").is_dir():
        print(f"{REAL / 'train_full'}: not found (road_defects_br's full-size train frames)", file=sys.stderr)
        sys.exit(2)
    with tempfile.TemporaryDirectory(prefix="roadtwin-crack-labels-") as tmp:
        out = args.out or Path(tmp)
        photos = out / "photos"
        photos.mkdir(parents=True, exist_ok=True)
        for image in sorted((REAL / "train_full" / "images").glob("*.jpg"))[args.photos_every - 1::args.photos_every]:
            if not (photos / image.name).exists():
                (photos / image.name).symlink_to(image.resolve())
        labels = str(REAL / "train_full" / "labels")
        run("reconstruct", "photos", str(photos), "--labels", labels, "-o", str(out / "lib_strokes"), reuse=args.reuse)
        run("reconstruct", "photos", str(photos), "--labels", labels, "--param", "crack_strokes=false",
            "-o", str(out / "lib_area"), reuse=args.reuse)
        renders = {name: make_arm(out, name, lib, args) for name, lib in
                   (("area", out / "lib_area"), ("strokes", out / "lib_strokes"), ("parametric", None))}
        arms = {name: frames_of(render) for name, render in renders.items()}
        contrast = {name: folder_contrasts(render) for name, render in renders.items()}
        contrast["real train labels"] = folder_contrasts(REAL / "train")
        real = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) == CRACK for f in sorted((REAL / "train" / "labels").glob("*.png"))]
        print(f"library area:    {library_stats(out / 'lib_area')}")
        print(f"library strokes: {library_stats(out / 'lib_strokes')}")
        print("| frames | n | with crack | crack px share | median crack 2A/P px | crack / pothole contrast C, C_core "
              "(instances) |\n|---|---|---|---|---|---|")
        for name, masks in [*((k, [m for _, _, m, _ in v]) for k, v in arms.items()), ("real train labels", real)]:
            s = crack_stats(masks)
            c = " / ".join(f"{np.median(v, axis=0)[0]:.3f}, {np.median(v, axis=0)[1]:.3f} ({len(v)})" if v else "-"
                           for v in contrast[name].values())
            print(f"| {name} | {s['frames']} | {s['crack_frames']} | {s['share_pct']:.3f} % | {s['width_px']:.2f} | {c} |")
        print(f"figure: {args.figure} (frames: {figure(arms, out, args.figure)})")


if __name__ == "__main__":
    main()
