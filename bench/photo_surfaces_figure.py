"""Figure: road surfaces cut from photos, each tiled 2 x 2, beside the procedural asphalt.

    .venv/bin/roadtwin reconstruct photo-surfaces ../shared/data/road_defects_br/train_full/images \
        --labels ../shared/data/road_defects_br/train_full/labels -o /tmp/photo_surfaces
    .venv/bin/python bench/photo_surfaces_figure.py /tmp/photo_surfaces -o docs/realism/photo_surfaces.jpg

Each row: the material's diffuse repeated 2 x 2 (two repeats of ``ST_TILE_M``, i.e. 8 m of
road a side, where a seam would show as a cross), then the texels around the wrap corner at
full resolution (80 cm of road: the seam runs through the middle both ways), then the source
frame with the window outlined. The first row is the procedural ``asphalt_worn``. Prints each
material's seam ratio (seam / interior mean absolute luminance difference; about 1 = no seam).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "plugins"))

from roadtwin_core.looks import ST_TILE_M, write_textures  # noqa: E402
from roadtwin_photo.rectify import PhotoRig  # noqa: E402
from roadtwin_photo.seamless import seam_ratio  # noqa: E402

PANEL = 360


def _label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    for colour, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(out, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, width, cv2.LINE_AA)
    return out


def _row(diffuse: np.ndarray, title: str, frame: np.ndarray | None) -> np.ndarray:
    tiled = cv2.resize(np.tile(diffuse, (2, 2, 1)), (PANEL, PANEL), interpolation=cv2.INTER_AREA)
    n = diffuse.shape[0]
    half = int(round(0.4 / ST_TILE_M * n))                       # 40 cm each side of the corner
    wrapped = np.roll(diffuse, (half, half), axis=(0, 1))[:2 * half, :2 * half]
    corner = cv2.resize(wrapped, (PANEL, PANEL), interpolation=cv2.INTER_NEAREST)
    ratio = max(seam_ratio(diffuse).values())
    panels = [_label(tiled, f"{title}: 2x2 repeats, 8 m"), _label(corner, f"wrap corner, 0.8 m (seam {ratio:.2f})")]
    panels.append(frame if frame is not None else np.full((PANEL, int(PANEL * 1.6), 3), 40, np.uint8))
    return np.hstack(panels)


def _frame_with_window(rec: dict) -> np.ndarray:
    rgb = cv2.imread(rec["frame"])
    rig = PhotoRig(**rec["rig"])
    (x0, x1), (y0, y1) = rec["window_road_m"]["x"], rec["window_road_m"]["y"]
    corners = np.array([[x0, y0], [x0, y1], [x1, y1], [x1, y0]], float)
    uv, _ = rig.project(corners, rgb.shape[1], rgb.shape[0])
    cv2.polylines(rgb, [np.round(uv).astype(np.int32)], True, (0, 255, 255), 3, cv2.LINE_AA)
    rgb = cv2.resize(rgb, (int(PANEL * 1.6), PANEL), interpolation=cv2.INTER_AREA)
    return _label(rgb, Path(rec["frame"]).name[:40])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("materials", type=Path, help="folder written by roadtwin reconstruct photo-surfaces")
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "docs/realism/photo_surfaces.jpg")
    args = ap.parse_args()
    meta = json.loads((args.materials / "materials.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        write_textures(tmp, seed=0)
        procedural = cv2.imread(str(Path(tmp) / "asphalt_worn_diffuse.png"))
    rows = [_row(procedural, "procedural asphalt_worn", None)]
    print(f"asphalt_worn (procedural): seam ratio {max(seam_ratio(procedural).values()):.2f}")
    for rec in meta["materials"]:
        diffuse = cv2.imread(str(args.materials / rec["diffuse"]))
        rows.append(_row(diffuse, rec["name"], _frame_with_window(rec)))
        print(f"{rec['name']}: window {rec['window_m']:g} m x{rec['repeats']}, seam ratio "
              f"{max(seam_ratio(diffuse).values()):.2f} (unblended crop {max(rec['seam_ratio_unblended'].values()):.2f}), "
              f"ground sample {rec['ground_sample_m'][0] * 1000:.1f}-{rec['ground_sample_m'][1] * 1000:.1f} mm/px")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
