"""Eight real survey frames beside eight roadtwin frames of the same rig (issue 22's "Must show");
writes ``docs/realism/real_vs_synthetic.jpg``.

    .venv/bin/python bench/real_vs_synth_figure.py                     # compose + render a small set (CPU, ~3 min)
    .venv/bin/python bench/real_vs_synth_figure.py --render /tmp/zs/render   # frames already rendered
    .venv/bin/python bench/real_vs_synth_figure.py --photos-every 30   # the figure in docs/realism (20 photos, ~1 min)

Real: ``road_defects_br/val`` (512x320, a DNIT survey camera; val is only looked at here, nothing
is fitted on it). Synthetic: a ``roadtwin render`` output folder, or, when none is given, the
recipe of ``docs/perception/efficientnet/make_frames.sh`` made small: photo defects reconstructed
from every ``--photos-every``-th ``train_full`` frame (train only), the highway layout with the ten
look-alike types weighted composed with that ``--library`` (props on), then ``--frames`` survey-rig
frames, ``--views defects:0.5:clear --randomize --classmap builtin:road_defects_br``.

Which frames: on each side, ``--tiles`` (8) spread evenly over the frames whose labels hold a
pothole or a crack (sorted by name / frame index), topped up with frames without one if too few
hold any, so neither side is picked for looks. Prints the frames chosen and each side's share of
pothole and crack pixels.
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

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "road_defects_br"
LOOKALIKE_WEIGHTS = {"oil_stain": 1.0, "tar_stain": 1.0, "sealed_crack": 1.5, "tyre_mark": 1.0, "wet_patch": 0.5,
                     "puddle": 0.5, "debris": 0.5, "patch_seam": 1.0, "worn_paint": 0.5, "ghost_paint": 0.5}
REAL_CLASS_IDS = {"crack": 2, "pothole": 3}          # road_defects_br/README.md


def spread(with_defect: list, others: list, n: int) -> list:
    """``n`` items evenly spaced over ``with_defect``, topped up from ``others`` when too few."""
    if len(with_defect) >= n:
        return [with_defect[i] for i in np.linspace(0, len(with_defect) - 1, n).round().astype(int)]
    return with_defect + others[: n - len(with_defect)]


def real_frames(val: Path, n: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    frames = []
    for image in sorted((val / "images").glob("*.jpg")):
        label = cv2.imread(str(val / "labels" / f"{image.stem}.png"), cv2.IMREAD_UNCHANGED)
        if label is None:
            fail(f"{image}: no label {val / 'labels' / (image.stem + '.png')}")
        frames.append((image.stem, image, label))
    defect_ids = list(REAL_CLASS_IDS.values())
    picked = spread([f for f in frames if np.isin(f[2], defect_ids).any()],
                    [f for f in frames if not np.isin(f[2], defect_ids).any()], n)
    return [(stem, cv2.imread(str(image)), label) for stem, image, label in picked]


def synthetic_frames(render: Path, n: int) -> list[tuple[str, np.ndarray, np.ndarray]]:
    meta = json.loads((render / "meta.json").read_text())
    class_ids = {c["name"]: c["id"] for c in meta["classes"]}
    ids = [class_ids[name] for name in REAL_CLASS_IDS]
    frames = [(fr["stem"], render / fr["files"]["rgb"],
               cv2.imread(str(render / fr["files"]["semantic"]), cv2.IMREAD_UNCHANGED)) for fr in meta["frames"]]
    picked = spread([f for f in frames if np.isin(f[2], ids).any()],
                    [f for f in frames if not np.isin(f[2], ids).any()], n)
    # to the real class ids, so both sides are counted the same way
    remap = np.zeros(256, np.uint8)
    for name, i in zip(REAL_CLASS_IDS, ids):
        remap[i] = REAL_CLASS_IDS[name]
    return [(stem, cv2.imread(str(image)), remap[label]) for stem, image, label in picked]


def make_render(out: Path, args) -> Path:
    """The make_frames.sh recipe, small: reconstruct -> compose (look-alikes, library) -> render."""
    from roadtwin_core.usd import read_layout, write_layout

    roadtwin = str(Path(sys.executable).with_name("roadtwin"))
    photos = out / "photos"
    photos.mkdir(parents=True, exist_ok=True)
    for image in sorted((REAL / "train_full" / "images").glob("*.jpg"))[args.photos_every - 1::args.photos_every]:
        (photos / image.name).symlink_to(image.resolve())
    (photos / "LICENSE").symlink_to((REAL / "LICENSE").resolve())
    layout = read_layout(REPO / "stages" / "highway.usda")
    layout.rules.type_weights.update(LOOKALIKE_WEIGHTS)
    write_layout(layout, out / "highway_lookalikes.usda")
    steps = [["reconstruct", "photos", str(photos), "--labels", str(REAL / "train_full" / "labels"), "-o",
              str(out / "lib")],
             ["compose", str(out / "highway_lookalikes.usda"), "--defects", str(args.defects), "--library",
              str(out / "lib"), "--seed", str(args.seed), "--no-preview", "-o", str(out / "hw")],
             ["render", str(out / "hw" / "town.usda"), "--rig", "survey", "--views", "defects:0.5:clear",
              "--randomize", "--classmap", "builtin:road_defects_br", "--frames", str(args.frames), "--size",
              args.size, "--formats", "mmseg", "--seed", str(args.seed), "--executor", "serial", "-o",
              str(out / "render")]]
    for step in steps:
        print("roadtwin", " ".join(step), flush=True)
        subprocess.run([roadtwin, *step], check=True)
    return out / "render"


def tile(stem: str, bgr: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    img = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
    cv2.putText(img, stem, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, stem, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def block(title: str, frames: list, size: tuple[int, int], cols: int) -> np.ndarray:
    tiles = [tile(stem, bgr, size) for stem, bgr, _ in frames]
    rows = [np.concatenate(tiles[i:i + cols], axis=1) for i in range(0, len(tiles), cols)]
    body = np.concatenate(rows, axis=0)
    head = np.full((34, body.shape[1], 3), 255, np.uint8)
    cv2.putText(head, title, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.65, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([head, body], axis=0)


def report(side: str, frames: list) -> None:
    labels = np.stack([cv2.resize(lab, (512, 320), interpolation=cv2.INTER_NEAREST) for _, _, lab in frames])
    share = {name: 100.0 * float((labels == i).mean()) for name, i in REAL_CLASS_IDS.items()}
    print(f"{side}: {', '.join(s for s, _, _ in frames)}")
    print(f"  label share of the {len(frames)} frames: pothole {share['pothole']:.2f} %, crack {share['crack']:.2f} %")


def fail(message: str) -> None:
    print(message, file=sys.stderr)
    sys.exit(2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--render", type=Path, default=None, help="a roadtwin render output folder (meta.json)")
    ap.add_argument("--real", type=Path, default=REAL / "val")
    ap.add_argument("--out", type=Path, default=None, help="scratch folder for the small render (default: a temp dir)")
    ap.add_argument("--frames", type=int, default=16, help="frames to render when --render is not given")
    ap.add_argument("--size", default="512x320")
    ap.add_argument("--photos-every", type=int, default=20, help="every N-th train_full frame is reconstructed")
    ap.add_argument("--defects", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tiles", type=int, default=8)
    ap.add_argument("--tile-size", default="512x320")
    ap.add_argument("--figure", type=Path, default=REPO / "docs" / "realism" / "real_vs_synthetic.jpg")
    args = ap.parse_args()

    size = tuple(int(v) for v in args.tile_size.split("x"))
    if not any((args.real / "images").glob("*.jpg")):
        fail(f"{args.real}: no images/*.jpg (a road_defects_br split: images/ and labels/)")
    if args.render is not None and not (args.render / "meta.json").is_file():
        fail(f"{args.render}: no meta.json (not a roadtwin render output folder)")
    real = real_frames(args.real, args.tiles)
    with tempfile.TemporaryDirectory(prefix="roadtwin-realism-") as tmp:
        render = args.render or make_render(args.out or Path(tmp), args)
        synthetic = synthetic_frames(render, args.tiles)
    report(f"real ({args.real})", real)
    report(f"synthetic ({render})", synthetic)
    cols = max(1, args.tiles // 2)
    figure = np.concatenate([
        block(f"real: road_defects_br/{args.real.name} (DNIT survey camera), {len(real)} frames", real, size, cols),
        np.full((12, cols * size[0], 3), 255, np.uint8),
        block("roadtwin: survey rig, photo-defect library + look-alikes + props, --randomize "
              "--classmap builtin:road_defects_br", synthetic, size, cols)], axis=0)
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    ok, data = cv2.imencode(".jpg", figure, [cv2.IMWRITE_JPEG_QUALITY, 85])
    tmp_figure = args.figure.with_suffix(".tmp.jpg")
    tmp_figure.write_bytes(data.tobytes())
    tmp_figure.replace(args.figure)
    print(f"wrote {args.figure} ({figure.shape[1]}x{figure.shape[0]}, {args.figure.stat().st_size / 1024:.0f} kB)")


if __name__ == "__main__":
    main()
