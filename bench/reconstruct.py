"""Benchmark of the stereo defect reconstructor (issue 4, item 2). Prints, asserts nothing.

1. Real ZED frames (tests/data/stereo_pothole, Fan et al.'s transformed disparity): pothole
   pixels vs the labels, F1 per frame and mean (target >= 0.9).
2. Disparity transformation on synthetic tilted/rolled roads: roll angle estimated vs true,
   std of the transformed road disparity outside the pothole vs the added noise.
3. Known bowl potholes at 1.5 m (exact disparity by ray-surface intersection + 0.1 px noise, and a
   rendered textured pair through OpenCV SGBM): volume error (target <= 10 %) and Hausdorff
   distance of the reconstructed surface to the true one (target <= 1 cm).

    .venv/bin/python bench/reconstruct.py
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
import roadtwin_stereo as rs
from roadtwin_stereo.synthetic import BowlScene, hausdorff_to_bowl, mesh_samples

DATA = ROOT / "tests" / "data" / "stereo_pothole"


def real_frames() -> None:
    print("== real frames: pothole pixels from the transformed disparity vs labels")
    st = rs.StereoDefects()
    scores = []
    for i in range(1, 6):
        t = time.perf_counter()
        r = st.run({"disparity": DATA / "disp_tg" / f"0{i}.png", "transformed": True})
        label = rs.load_label(DATA / "label" / f"0{i}.png")
        pred = r.labels > 0
        tp = float((pred & label).sum())
        p, rc = tp / max(pred.sum(), 1), tp / max(label.sum(), 1)
        scores.append(rs.f1_score(pred, label))
        print(f"frame 0{i}: F1 {scores[-1]:.3f}  precision {p:.3f}  recall {rc:.3f}  "
              f"instances {int(r.labels.max())}  {time.perf_counter() - t:.2f} s")
    print(f"mean F1 {np.mean(scores):.3f}  (target >= 0.9)")


def roll_angles() -> None:
    print("== disparity transformation: roll angle and flatness (synthetic road, 0.05 px noise)")
    for roll, tilt in ((0.0, 45.0), (5.0, 45.0), (-8.0, 50.0), (12.0, 40.0)):
        sc = BowlScene(tilt_deg=tilt, roll_deg=roll, distance=3.0, offset=(0.3, 0.2))
        d = sc.disparity(0.05, seed=1)
        t = time.perf_counter()
        dt, m = rs.transform_disparity(d)
        el = time.perf_counter() - t
        z = sc.depth_map()
        v, u = np.mgrid[0:sc.height, 0:sc.width].astype(float)
        p = np.stack([(u - sc.K[0, 2]) / sc.f, (v - sc.K[1, 2]) / sc.f, np.ones_like(u)], -1) * z[..., None]
        loc = sc.to_local(p.reshape(-1, 3)).reshape(p.shape)
        out = loc[..., 0] ** 2 + loc[..., 1] ** 2 > sc.radius ** 2
        print(f"camera roll {roll:+5.1f} deg: theta true {np.degrees(sc.roll_angle_image):+8.4f}  est "
              f"{np.degrees(m.theta):+8.4f} deg  (err {np.degrees(m.theta - sc.roll_angle_image):+.4f})  "
              f"raw std {np.std(d[out]):.2f} px -> transformed std {np.std(dt[out]):.3f} px  {el:.2f} s")


def bowls() -> None:
    print("== known bowls at 1.5 m: volume error and Hausdorff distance")
    st = rs.StereoDefects()
    cases = [dict(tilt_deg=30, roll_deg=2.0, depth=0.05, radius=0.25, offset=(0.05, -0.03)),
             dict(tilt_deg=45, roll_deg=-4.0, depth=0.03, radius=0.15, offset=(-0.1, 0.05)),
             dict(tilt_deg=20, roll_deg=0.0, depth=0.08, radius=0.30, offset=(0.0, 0.0))]
    for kw in cases:
        sc = BowlScene(distance=1.5, **kw)
        for how in ("exact+0.1px", "SGBM pair"):
            t = time.perf_counter()
            if how == "SGBM pair":
                left, right = sc.stereo_pair(seed=3)
                r = st.run({"left": left, "right": right, "K": sc.K, "baseline": sc.baseline})
            else:
                r = st.run({"disparity": sc.disparity(0.1, seed=2), "K": sc.K, "baseline": sc.baseline})
            el = time.perf_counter() - t
            if not r.models:
                print(f"D {kw['depth'] * 100:.0f} cm R {kw['radius'] * 100:.0f} cm {how}: nothing reconstructed")
                continue
            m, inst = r.models[0], r.instances[0]
            hd, mean_d = hausdorff_to_bowl(sc, inst.to_camera(mesh_samples(m.vertices, m.faces)))
            print(f"D {kw['depth'] * 100:.0f} cm R {kw['radius'] * 100:.0f} cm tilt {kw['tilt_deg']:.0f} {how:12s}: "
                  f"volume {m.volume_m3 * 1e3:.3f} L vs {sc.volume * 1e3:.3f} L (err {100 * (m.volume_m3 / sc.volume - 1):+.2f} %)  "
                  f"depth {m.depth_m * 100:.2f} cm  Hausdorff {hd * 1000:.1f} mm (mean {mean_d * 1000:.2f} mm)  {el:.2f} s")


if __name__ == "__main__":
    real_frames()
    roll_angles()
    bowls()
