"""Figure: stereo-made textured potholes (issue 22, item 1) from Fan et al.'s stereo pothole frames,
placed in a small town and rendered by roadtwin (CPU).

For each frame: its transformed disparity through the nominal `inspection` rig
(``roadtwin_stereo.texture.disparity_from_transformed``; the normalised maps lost the true scale,
so depth is the measured relief at a nominal scale), the stereo reconstructor with the left rgb
as texture, one library asset per pothole. The assets go into a 30 m x 7 m lane (compose
--library, potholes only), and roadtwin renders one view from 0.55 m behind and 0.75 m above each placed
stereo pothole. Top row: the frames' rgb around the pothole; middle: each asset's texture over a
checkerboard (alpha); bottom: the rendered town.

    .venv/bin/python bench/stereo_texture_figure.py [--frames 01,03,06,09] [--out docs/realism/stereo_potholes.jpg]
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
import triangle

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "plugins")]
import roadtwin_stereo as rs  # noqa: E402
from roadtwin_stereo.texture import nominal_inputs  # noqa: E402

from roadtwin_core import ComposeRules, RoadSegment, TownLayout  # noqa: E402
from roadtwin_core.usd import read_defect_asset, write_layout  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "stereo_pothole"
TILE = 300   # px per panel


def reconstruct(frame: str, lib: Path) -> tuple[np.ndarray, list[Path]]:
    """One frame's textured assets in ``lib/<frame>``; returns the rgb crop around its pothole."""
    st = rs.StereoDefects()
    r = st.run({**nominal_inputs(rs.load_disparity(DATA / "disp_tg" / f"{frame}.png")),
                "rgb": DATA / "rgb" / f"{frame}.jpg", "source": str(DATA / "disp_tg" / f"{frame}.png")})
    paths = st.write(r, lib / frame)
    rgb = cv2.imread(str(DATA / "rgb" / f"{frame}.jpg"))
    vs, us = np.nonzero(r.labels)
    if len(vs):
        cv2.drawContours(rgb, cv2.findContours((r.labels > 0).astype(np.uint8), cv2.RETR_EXTERNAL,
                                               cv2.CHAIN_APPROX_NONE)[0], -1, (0, 255, 255), 3)
        half = int(max(np.ptp(us), np.ptp(vs)) * 0.8) + 20
        cu, cv_ = int(us.mean()), int(vs.mean())
        rgb = rgb[max(cv_ - half, 0):cv_ + half, max(cu - half, 0):cu + half]
    return rgb, paths


def over_checker(path: Path) -> np.ndarray:
    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(float)
    chk = ((np.indices(a.shape[:2]).sum(0) // 12) % 2)[..., None] * 60.0 + 110.0
    al = a[..., 3:] / 255.0
    return (a[..., :3] * al + chk * (1 - al)).astype(np.uint8)


def fit(img: np.ndarray, size: int = TILE) -> np.ndarray:
    h, w = img.shape[:2]
    s = size / max(h, w)
    img = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    out = np.full((size, size, 3), 255, np.uint8)
    y, x = (size - img.shape[0]) // 2, (size - img.shape[1]) // 2
    out[y:y + img.shape[0], x:x + img.shape[1]] = img
    return out


def town_views(lib: Path, work: Path, n: int) -> list[np.ndarray]:
    """Compose a lane with the library's potholes and render one view behind each of ``n`` placed ones."""
    flat = work / "flatlib"
    flat.mkdir()
    (flat / "textures").mkdir()
    for p in lib.rglob("*"):                       # one folder: compose --library reads one
        if p.is_file() and p.parent.name == "textures":
            (flat / "textures" / p.name).write_bytes(p.read_bytes())
        elif p.is_file() and p.suffix == ".usda":
            (flat / p.name).write_bytes(p.read_bytes())
    poly = np.array([[0, 0], [30, 0], [30, 7], [0, 7]], dtype=float)
    t = triangle.triangulate({"vertices": poly, "segments": [[0, 1], [1, 2], [2, 3], [3, 0]]}, "p")
    seg = RoadSegment("lane", "driving", t["vertices"], t["triangles"], np.array([[0, 3.5], [30, 3.5]]))
    write_layout(TownLayout("Town", [seg], ComposeRules(defect_count=10, seed=1, surface="flat",
                                                        type_weights={"pothole": 1.0}, models_per_type=1)),
                 work / "road.usda")
    exe = ROOT / ".venv" / "bin" / "roadtwin"
    subprocess.run([str(exe), "compose", str(work / "road.usda"), "-o", str(work / "town"), "--library", str(flat),
                    "--no-preview", "--executor", "serial", "--props", "none"], check=True, capture_output=True)
    from pxr import Usd

    stage = Usd.Stage.Open(str(work / "town" / "town.usda"))
    poses = []
    for inst in stage.GetPrimAtPath("/Town/Defects").GetChildren():
        if inst.GetAttribute("roadtwin:defect:model").Get().startswith("lib_") and len(poses) < n:
            x, y, _ = inst.GetAttribute("roadtwin:defect:poseXYYaw").Get()
            poses.append({"position": [x - 0.55, y, 0.75], "yaw_deg": 0.0, "pitch_deg": -50.0})
    del stage
    (work / "poses.json").write_text(json.dumps(poses))
    subprocess.run([str(exe), "render", str(work / "town" / "town.usda"), "-o", str(work / "render"), "--poses",
                    str(work / "poses.json"), "--frames", str(len(poses)), "--size", "640x480", "--hfov", "45"],
                   check=True, capture_output=True)
    frames = sorted((work / "render").rglob("*.png"))
    rgb = [f for f in frames if "rgb" in f.parts[-2] or f.parent.name in ("image_2", "rgb", "images")]
    return [cv2.imread(str(f)) for f in (rgb or frames)[:n]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="01,03,06,09")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "realism" / "stereo_potholes.jpg")
    a = ap.parse_args()
    frames = a.frames.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        crops, textures = [], []
        for fr in frames:
            crop, paths = reconstruct(fr, work / "lib")
            crops.append(fit(crop))
            for p in paths:
                m = read_defect_asset(p)
                print(f"frame {fr}: {p.stem}: depth {m.depth_m * 100:.1f} cm (nominal scale), area {m.area_m2:.3f} m2, "
                      f"texture {cv2.imread(m.look.textures['diffuse']).shape[1::-1]} px")
            textures.append(fit(over_checker(Path(read_defect_asset(paths[0]).look.textures["diffuse"]))))
        views = [fit(v) for v in town_views(work / "lib", work, len(frames))]
    rows = [np.hstack(crops), np.hstack(textures), np.hstack(views + [np.full((TILE, TILE, 3), 255, np.uint8)] *
                                                             (len(frames) - len(views)))]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
