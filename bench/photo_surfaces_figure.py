"""Figure: road surfaces cut from photos over 8 m x 8 m of road, the window repeated (before)
beside the quilted tile (now), with the procedural asphalt; prints how periodic each is.

    .venv/bin/roadtwin reconstruct photo-surfaces ../shared/data/road_defects_br/train_full/images \
        --labels ../shared/data/road_defects_br/train_full/labels -o /tmp/photo_surfaces
    .venv/bin/roadtwin reconstruct photo-surfaces ../shared/data/road_defects_br/train_full/images \
        --labels ../shared/data/road_defects_br/train_full/labels --param quilt=false -o /tmp/photo_surfaces_repeated
    .venv/bin/python bench/photo_surfaces_figure.py /tmp/photo_surfaces --before /tmp/photo_surfaces_repeated \
        -o docs/realism/photo_surfaces.jpg

Each row: 8 m x 8 m of road as the renderer tiles the material (two ``ST_TILE_M`` repeats a
side; travel runs left to right), first as the one window repeated k x k (``--before``, the
material of the same name), then quilted from the windows of that kind of road; then the texels
around the wrap corner of the quilted tile at full resolution (80 cm of road: the wrap runs
through the middle both ways); then the source frame with its window outlined. The first row is
the procedural ``asphalt_worn``. Captions sit on a band above the panels, drawn once.

Printed per material: the seam ratio (seam / interior mean absolute luminance difference,
about 1 = no seam) and the *window-period correlation*: the normalised autocorrelation of the
luminance at a lag of the window's side (2 m), along travel and across, over the 8 m area (the
larger of the two). A window repeated k x k measures 1.0; an aperiodic road near 0. The tile
itself still repeats every ``ST_TILE_M`` (4 m): the st convention of the town's textures.
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
from roadtwin_photo.seamless import period_correlation, seam_ratio  # noqa: E402

PANEL = 360
CAPTION = 30
AREA_M = 8.0


def _captioned(img: np.ndarray, text: str) -> np.ndarray:
    """The panel under a dark caption band, the text drawn once (no outline: it would shift)."""
    band = np.full((CAPTION, img.shape[1], 3), 24, np.uint8)
    cv2.putText(band, text, (6, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 235), 1, cv2.LINE_AA)
    return np.vstack([band, img])


def _area(diffuse: np.ndarray) -> np.ndarray:
    """AREA_M x AREA_M of road tiled with the texture (texture columns = travel, left to right)."""
    reps = int(round(AREA_M / ST_TILE_M))
    return cv2.resize(np.tile(diffuse, (reps, reps, 1)), (PANEL, PANEL), interpolation=cv2.INTER_AREA)


def window_period_correlation(diffuse: np.ndarray, window_m: float) -> float:
    """The larger of the along- and across-travel autocorrelations at the window's period (the
    tile repeats every ST_TILE_M, so the circular one over the tile is the one over 8 m)."""
    lag = int(round(window_m / ST_TILE_M * diffuse.shape[0]))
    return max(period_correlation(diffuse[..., ::-1], lag).values())


def _corner(diffuse: np.ndarray) -> np.ndarray:
    n = diffuse.shape[0]
    half = int(round(0.4 / ST_TILE_M * n))                       # 40 cm each side of the corner
    wrapped = np.roll(diffuse, (half, half), axis=(0, 1))[:2 * half, :2 * half]
    return cv2.resize(wrapped, (PANEL, PANEL), interpolation=cv2.INTER_NEAREST)


def _frame_with_window(rec: dict) -> np.ndarray:
    rgb = cv2.imread(rec["frame"])
    rig = PhotoRig(**rec["rig"])
    for i, src in enumerate(rec.get("sources") or [rec]):
        if src["frame"] != rec["frame"]:
            continue
        (x0, x1), (y0, y1) = src["window_road_m"]["x"], src["window_road_m"]["y"]
        corners = np.array([[x0, y0], [x0, y1], [x1, y1], [x1, y0]], float)
        uv, _ = rig.project(corners, rgb.shape[1], rgb.shape[0])
        cv2.polylines(rgb, [np.round(uv).astype(np.int32)], True, (0, 255, 255), 3, cv2.LINE_AA)
    return cv2.resize(rgb, (int(PANEL * 1.6), PANEL), interpolation=cv2.INTER_AREA)


def _row(name: str, before: np.ndarray | None, after: np.ndarray, window_m: float, rec: dict | None) -> np.ndarray:
    seam = max(seam_ratio(after).values())
    blank = np.full((PANEL, PANEL, 3), 40, np.uint8)
    r_after = window_period_correlation(after, window_m)
    if before is None:
        left = _captioned(blank, "")
    else:
        left = _captioned(_area(before), f"{name}: {window_m:g} m window x{int(ST_TILE_M / window_m)}, "
                          f"r={window_period_correlation(before, window_m):.2f}")
    what = "procedural asphalt_worn" if rec is None else f"quilted from {len(rec.get('sources') or [rec])} window(s)"
    panels = [left, _captioned(_area(after), f"{what}, r={r_after:.2f}"),
              _captioned(_corner(after), f"wrap corner 0.8 m, seam {seam:.2f}")]
    if rec is None:
        panels.append(_captioned(np.full((PANEL, int(PANEL * 1.6), 3), 40, np.uint8), ""))
    else:
        panels.append(_captioned(_frame_with_window(rec), Path(rec["frame"]).name[:48]))
    return np.hstack(panels)


def _header(width: int) -> np.ndarray:
    text = (f"{AREA_M:g} m x {AREA_M:g} m of road each (travel left to right); r = autocorrelation at the window's "
            f"period (1 = repeated, 0 = aperiodic)")
    band = np.full((CAPTION, width, 3), 0, np.uint8)
    cv2.putText(band, text, (6, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return band


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("materials", type=Path, help="folder written by roadtwin reconstruct photo-surfaces")
    ap.add_argument("--before", type=Path, help="the same run with --param quilt=false (window repeated k x k)")
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "docs/realism/photo_surfaces.jpg")
    args = ap.parse_args()
    meta = json.loads((args.materials / "materials.json").read_text())
    before = {}
    if args.before:
        before = {r["name"]: r for r in json.loads((args.before / "materials.json").read_text())["materials"]}
    with tempfile.TemporaryDirectory() as tmp:
        write_textures(tmp, seed=0)
        procedural = cv2.imread(str(Path(tmp) / "asphalt_worn_diffuse.png"))
    rows = [_row("asphalt_worn", None, procedural, 2.0, None)]
    print(f"asphalt_worn (procedural): seam ratio {max(seam_ratio(procedural).values()):.2f}, 2 m period "
          f"correlation {window_period_correlation(procedural, 2.0):.3f}")
    for rec in meta["materials"]:
        after = cv2.imread(str(args.materials / rec["diffuse"]))
        old = before.get(rec["name"])
        old_img = cv2.imread(str(args.before / old["diffuse"])) if old else None
        rows.append(_row(rec["name"], old_img, after, rec["window_m"], rec))
        line = (f"{rec['name']}: window {rec['window_m']:g} m, {len(rec.get('sources') or [rec])} window(s); "
                f"seam ratio {max(seam_ratio(after).values()):.2f}; window-period correlation "
                f"{window_period_correlation(after, rec['window_m']):.3f}")
        if old_img is not None:
            line += (f" (repeated x{old['repeats']}: {window_period_correlation(old_img, rec['window_m']):.3f}, seam "
                     f"{max(seam_ratio(old_img).values()):.2f})")
        print(line)
    body = np.vstack(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack([_header(body.shape[1]), body]), [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
