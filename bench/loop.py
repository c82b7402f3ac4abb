"""The loop back (issue 20, item 5): drive a twin, reconstruct it from the drive's sensors, and
compare with the twin's own truth.

For each case: compose the layout (``roadtwin compose``), drive it (``roadtwin drive --route auto``
with a rig of a stereo pair and a Livox Mid-360-like LiDAR), then

- ``reconstruct surface`` (the ``lidar_surface`` reconstructor) on the drive's LiDAR scans, each
  point moved to the map with the bag's body pose at its own time (de-skew) and the sensor's
  /tf_static extrinsic, road points by their per-point labels, within CORRIDOR_M of the path; scored by the height error of the
  surface's vertices against the collision mesh (vertical rays): RMSE, all vertices and those off
  any defect;
- ``reconstruct defects`` (``stereo_defects``) on every stereo pair, disparity from OpenCV SGBM,
  refined to sub-pixel by Lucas-Kanade along the rows (``--subpixel``; 0 = off), on
  the rendered images (never the renderer's depth), cropped to the rows that see road within
  ROI_M (from the camera's pose and the road height under it), with the frame's paved pixels
  (semantic truth, eroded 3 px) as the road mask a segmentation network would give; for each true pothole in view (its ground-
  truth instance has >= MIN_PX pixels, none on the image border) within 10 m of the camera
  (horizontal distance to its centre): *found* if detected pixels cover >= half of its true
  pixels; the reconstructed model whose world footprint overlaps it most gives the footprint IoU
  (shapely, world XY) and the depth error (model depth - the defect's roadtwin:defect:depthM).
  Detections lying mostly off every true defect are counted as false.

Cases: ``town`` = the sample town as the README composes it (flat road); ``highway_D`` = the
highway layout (2 % crown on the lanes, 3 % shoulders, grades to 4 %, dense defects) with
``--surface iso8608:D``: the undulating road with several potholes a frame.

    PYTHONPATH=.:plugins .venv/bin/python bench/loop.py [--cases town,highway_D] [--duration 3]
        [--size 1280x720] [--out out/loop] [--reuse] [--subpixel 6,2 | 0]

Targets (issue 20): surface RMSE <= 5 mm; footprint IoU >= 0.8 and depth error <= 1 cm within
10 m; >= 95 % of potholes in view found on undulating roads.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "plugins"), str(ROOT / "bench")]
from _loop_data import PAVED, Bag, load_truth  # noqa: E402

CASES = {"town": ("stages/town.usda", []),
         "highway_D": ("stages/highway.usda", ["--surface", "iso8608:D", "--props", "none"])}
MIN_PX = 30
NEAR_M = 10.0
ROI_M = 15.0           # stereo: image rows whose road lies within this (m)
SUBPIXEL = (6.0, 2.0)  # stereo: LK window (px), chosen on tests/plugins/test_stereo_subpixel.py's scenes
CORRIDOR_M = 6.0       # LiDAR road points kept within this of the driven path
RIG = """name = "loop"

[[sensor]]
name = "lidar"
type = "lidar"
rate_hz = 10
xyz = [0.3, 0.0, 1.0]
ypr_deg = [0.0, -45.0, 0.0]

[[sensor]]
name = "stereo"
type = "stereo"
rate_hz = 10
xyz = [0.6, 0.06, 0.95]
ypr_deg = [0.0, -12.0, 0.0]
[sensor.params]
width = {w}
height = {h}
hfov_deg = 80.0
baseline_m = 0.12
max_subframes = 3
"""


def _log(what: str, t0: float) -> None:
    print(f"  {what} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)


def _run(cmd: list[str]) -> None:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "roadtwin_core.cli", *cmd], check=True, cwd=ROOT)
    print(f"  {' '.join(cmd[:1])}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)


def prepare(case: str, out: Path, args) -> tuple[Path, Path]:
    """Compose the case's town and drive it (kept with --reuse)."""
    layout, extra = CASES[case]
    stage = out / case / "town" / "town.usda"
    if not (args.reuse and stage.exists()):
        _run(["compose", layout, "-o", str(stage.parent), "--no-preview", *extra])
    w, h = (int(v) for v in args.size.split("x"))
    rig = out / "rig.toml"
    rig.write_text(RIG.format(w=w, h=h))
    drive = out / case / "drive"
    if not (args.reuse and (drive / "summary.json").exists()):
        length = args.speed / 3.6 * args.duration + 5.0   # auto picks the stretch of this length with most defects
        _run(["drive", str(stage), "-o", str(drive), "--rig", str(rig), "--duration", str(args.duration),
              "--speed", str(args.speed), "--length", f"{length:.1f}", "--no-rerun"])
    return stage, drive


def surface_figures(bag: Bag, classes: list[str], truth) -> dict:
    """Reconstruct the surface from the road points within CORRIDOR_M of the driven path (the
    Mid-360 reaches 40 m; farther road is sparse, and the vertex fit is the slow part)."""
    from scipy.spatial import cKDTree

    from roadtwin_lidar import LidarSurfaceReconstructor

    path = cKDTree(bag.body_poses()(np.linspace(0, 1e3, 20001))[:, :2, 3])
    scans = []
    for p, lab in bag.lidar_world():
        near = path.query(p[:, :2], distance_upper_bound=CORRIDOR_M)[0] < CORRIDOR_M
        scans.append((p[near], lab[near]))
    road = [i for i, n in enumerate(classes) if n in PAVED]
    surf = LidarSurfaceReconstructor().run({"frames": [p for p, _ in scans], "labels": [lab for _, lab in scans],
                                            "poses": np.tile(np.eye(4), (len(scans), 1, 1)), "road_labels": road,
                                            "source": str(bag.dir)})
    v = surf.world_vertices()
    err = v[:, 2] - truth.height(v[:, :2])
    ok = np.isfinite(err)
    import shapely

    on_defect = np.zeros(len(v), bool)
    for geom in truth.footprints.values():
        on_defect |= shapely.contains_xy(geom.buffer(0.05), v[:, 0], v[:, 1])
    rms = lambda e: float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")
    return {"scans": len(scans), "vertices": int(ok.sum()), "rmse_mm": 1000 * rms(err[ok]),
            "rmse_off_defects_mm": 1000 * rms(err[ok & ~on_defect]),
            "median_abs_mm": 1000 * float(np.median(np.abs(err[ok]))), "bias_mm": 1000 * float(np.mean(err[ok]))}


def _model_footprint(m, inst, cam_to_world):
    from shapely.geometry import Polygon

    b = inst.to_camera(m.vertices[m.boundary] * [1, 1, 0])
    w = b @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
    return Polygon(w[:, :2]).buffer(0)


def frame_figures(fr: dict, result, instances: dict, truth) -> dict:
    """Per frame: the true potholes in view within NEAR_M, found or not, IoU and depth error of
    the best-overlapping model; detections lying mostly off any true defect."""
    gt, det = fr["instance"], result.labels > 0
    cam = fr["cam_to_world"][:3, 3]
    border = np.zeros_like(gt, bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    feet = [_model_footprint(m, i, fr["cam_to_world"]) for m, i in zip(result.models, result.instances)]
    rows = []
    for iid in np.unique(gt[gt > 0]):
        did = instances.get(str(int(iid)))
        d = truth.defects.get(did)
        px = gt == iid
        if d is None or d["type"] != "pothole" or px.sum() < MIN_PX or (px & border).any():
            continue
        dist = float(np.hypot(*(d["xy"] - cam[:2])))
        row = {"defect": did, "dist_m": dist, "found": bool(det[px].mean() >= 0.5), "iou": 0.0, "depth_err_m": None}
        true_foot = truth.footprints[did]
        ious = [f.intersection(true_foot).area / max(f.union(true_foot).area, 1e-12) for f in feet]
        if ious and max(ious) > 0:
            k = int(np.argmax(ious))
            row["iou"] = float(ious[k])
            row["depth_err_m"] = float(result.models[k].depth_m - d["depth_m"])
        rows.append(row)
    on_true = gt > 0
    false = sum(1 for i in range(1, int(result.labels.max()) + 1) if on_true[result.labels == i].mean() < 0.5)
    return {"rows": rows, "detections": int(result.labels.max()), "false": false}


def road_rows(fr: dict, truth, reach_m: float) -> int:
    """First image row whose centre ray meets the road within ``reach_m`` (horizontal): the
    region of interest a road-inspection camera looks at (its mounting is known), so the sky,
    trees and far road above it are not modelled as road."""
    T, K = fr["cam_to_world"], fr["K"]
    h = T[2, 3] - truth.height(T[None, :2, 3])[0]
    v = np.arange(fr["left"].shape[0], dtype=np.float64)
    ray = np.stack([np.zeros_like(v), (v - K[1, 2]) / K[1, 1], np.ones_like(v)], -1) @ T[:3, :3].T
    down = ray[:, 2] < 0
    dist = np.where(down, h / np.maximum(-ray[:, 2], 1e-9) * np.hypot(ray[:, 0], ray[:, 1]), np.inf)
    inside = np.flatnonzero(dist <= reach_m)
    return int(inside[0]) if len(inside) else 0


def _crop(fr: dict, v0: int) -> dict:
    out = dict(fr)
    for k in ("left", "right", "instance", "depth", "semantic"):
        out[k] = fr[k][v0:]
    out["K"] = fr["K"].copy()
    out["K"][1, 2] -= v0
    return out


def road_mask(semantic: np.ndarray, classes: list[str]) -> np.ndarray:
    """Paved pixels of the frame's semantic truth, eroded 3 px (stands in for a road
    segmentation network's mask, as ``reconstruct surface --masks`` takes one)."""
    import cv2

    paved = np.isin(semantic, [i for i, n in enumerate(classes) if n in PAVED])
    return cv2.erode(paved.astype(np.uint8), np.ones((7, 7), np.uint8))


def stereo_figures(bag: Bag, instances: dict, truth, classes: list[str],
                   subpixel: tuple[float, float] = SUBPIXEL) -> dict:
    from roadtwin_stereo import StereoDefects

    rec = StereoDefects()
    rows, det, false, frames, per_frame = [], 0, 0, 0, []
    for k, fr in enumerate(bag.stereo_frames()):
        fr = _crop(fr, road_rows(fr, truth, ROI_M))
        zmin = float(np.nanmin(np.where(fr["depth"] > 0, fr["depth"], np.nan)))
        maxd = int(16 * np.ceil(1.2 * fr["K"][0, 0] * fr["baseline"] / zmin / 16))
        params = rec.Params(max_disparity=max(16, maxd), subpixel_sigma_u_px=subpixel[0],
                            subpixel_sigma_v_px=subpixel[1])
        res = rec.run({"left": fr["left"], "right": fr["right"], "K": fr["K"], "baseline": fr["baseline"],
                       "road_mask": road_mask(fr["semantic"], classes), "source": f"frame_{k:03d}"}, params)
        f = frame_figures(fr, res, instances, truth)
        rows += f["rows"]
        det += f["detections"]
        false += f["false"]
        frames += 1
        per_frame.append(sum(1 for r in f["rows"] if r["dist_m"] <= NEAR_M))
    near = [r for r in rows if r["dist_m"] <= NEAR_M]
    matched = [r for r in near if r["depth_err_m"] is not None]
    iou = np.array([r["iou"] for r in near]) if near else np.zeros(0)
    derr = np.abs([r["depth_err_m"] for r in matched]) if matched else np.zeros(0)
    return {"frames": frames, "potholes_in_view_10m": len(near), "unique_potholes": len({r["defect"] for r in near}),
            "per_frame_max": max(per_frame or [0]), "per_frame_mean": float(np.mean(per_frame or [0])),
            "found_share": float(np.mean([r["found"] for r in near])) if near else float("nan"),
            "found_share_all_dist": float(np.mean([r["found"] for r in rows])) if rows else float("nan"),
            "iou_median": float(np.median(iou)) if len(iou) else float("nan"),
            "iou_median_matched": float(np.median([r["iou"] for r in matched])) if matched else float("nan"),
            "matched": len(matched),
            "iou_ge_0.8_share": float(np.mean(iou >= 0.8)) if len(iou) else float("nan"),
            "depth_err_median_mm": 1000 * float(np.median(derr)) if len(derr) else float("nan"),
            "depth_err_le_1cm_share": float(np.mean(derr <= 0.01)) if len(derr) else float("nan"),
            "detections": det, "false_detections": false, "rows": near}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="town,highway_D")
    ap.add_argument("--duration", type=float, default=3.0, help="simulated seconds per drive")
    ap.add_argument("--speed", type=float, default=20.0, help="km/h")
    ap.add_argument("--size", default="1280x720", help="stereo image size WxH")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "loop")
    ap.add_argument("--reuse", action="store_true", help="keep composed towns and drives already in --out")
    ap.add_argument("--subpixel", default=",".join(f"{x:g}" for x in SUBPIXEL),
                    help="Lucas-Kanade refinement window of SGBM's disparity: sigma along,across the rows (px); "
                    "0 = SGBM's own sub-pixel step")
    args = ap.parse_args()
    subpixel = tuple(float(x) for x in (args.subpixel + ",2").split(",")[:2])
    args.out.mkdir(parents=True, exist_ok=True)
    report = {}
    for case in args.cases.split(","):
        stage, drive = prepare(case, args.out, args)
        summary = json.loads((drive / "summary.json").read_text())
        t0 = time.perf_counter()
        truth = load_truth(stage)
        _log(f"{case}: truth read", t0)
        bag = Bag(drive)
        s = surface_figures(bag, summary["classes"], truth)
        _log(f"{case}: surface reconstructed and scored", t0)
        st = stereo_figures(bag, summary["instances"], truth, summary["classes"], subpixel)
        _log(f"{case}: stereo frames reconstructed and scored", t0)
        report[case] = {"surface": s, "stereo": {k: v for k, v in st.items() if k != "rows"}, "observations": st["rows"]}
        print(f"== {case}: {summary['driven_m']:.1f} m, {summary['route']}")
        print(f"surface ({s['scans']} scans, {s['vertices']} vertices): height RMSE {s['rmse_mm']:.1f} mm "
              f"(off defects {s['rmse_off_defects_mm']:.1f} mm; median |err| {s['median_abs_mm']:.1f} mm, "
              f"bias {s['bias_mm']:+.1f} mm)   target <= 5 mm")
        how = "SGBM" if subpixel[0] == 0 else f"SGBM + sub-pixel LK {subpixel[0]:g}x{subpixel[1]:g} px"
        print(f"stereo ({st['frames']} frames, {how}): {st['potholes_in_view_10m']} pothole views within {NEAR_M:g} m "
              f"({st['unique_potholes']} potholes; up to {st['per_frame_max']} a frame, mean "
              f"{st['per_frame_mean']:.1f}): found {100 * st['found_share']:.1f} % (target >= 95 %; at any distance "
              f"{100 * st['found_share_all_dist']:.1f} %)")
        print(f"  footprint IoU (0 where no model overlaps) median {st['iou_median']:.2f}, share >= 0.8: "
              f"{100 * st['iou_ge_0.8_share']:.0f} %; over the {st['matched']} views with a model on the pothole: "
              f"median {st['iou_median_matched']:.2f} "
              f"(target IoU >= 0.8); |depth error| median {st['depth_err_median_mm']:.1f} mm, share <= 1 cm: "
              f"{100 * st['depth_err_le_1cm_share']:.0f} % (target <= 1 cm); detections {st['detections']}, "
              f"of which off every true defect {st['false_detections']}")
    (args.out / "loop.json").write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
