"""Render benchmark: G-buffer and shaded-RGB frames/s at 640x480 on the composed sample town,
and event-camera events/s. Not a test: it asserts nothing.

Two steps, so the timed part needs only numpy + warp (no USD, no roadtwin) on a GPU machine:

    # here (roadtwin installed): compose stages/town.usda, save triangles + labels + poses
    .venv/bin/python bench/render.py --prepare bench_town.npz
    # anywhere with numpy + warp (copy bench/render.py, plugins/roadtwin_warp_render/raycast.py,
    # roadtwin_core/render/events.py and the .npz, keeping the relative paths):
    python bench/render.py --mesh bench_town.npz --device cuda
    # both in one go on this machine (CPU):
    .venv/bin/python bench/render.py

``raycast.py`` (the renderer's kernels) and ``events.py`` (the event simulator) are loaded by
file path. Figures: G-buffer (depth, normal, class, instance, face id per pixel; one ray per
pixel), RGB (G-buffer + textured shading from the stage's materials: MIP-mapped diffuse,
roughness and normal lookups + a shadow ray per lit pixel), stereo (both views'
G-buffer and RGB + the occlusion rays), each over the prepared random lane poses; events: a
continuous 8 m/s drive rendered at 500 Hz, then the event simulator alone (events/s and frames/s).
On the CPU the G-buffer is also timed with open3d's Embree ray caster when open3d is importable
(the renderer's default CPU backend).
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent


def prepare(out: Path, stage: Path | None, poses: int, seed: int, ev_frames: int) -> None:
    """Compose the sample town (unless a stage is given) and save what the timed part needs."""
    from roadtwin_core import get_plugin_manager
    from roadtwin_core.apps.compose.run import compose
    from roadtwin_core.render import GroundSampler, build_render_mesh, lane_trajectory, sample_lane_poses, stage_lanes
    from roadtwin_core.usd import load_town

    with tempfile.TemporaryDirectory() as tmp:
        if stage is None:
            stage = compose(REPO / "stages/town.usda", Path(tmp) / "town", preview=False).town
        town = load_town(stage, looks=True)
        mesh = build_render_mesh(town, get_plugin_manager().registry("defect_types").keys())
        lanes = stage_lanes(stage)
    ground = GroundSampler(mesh)
    rng = np.random.default_rng(seed)
    cams = sample_lane_poses(lanes, poses, rng, ground)
    times, traj = lane_trajectory(lanes, rng, ground, speed=8.0, rate_hz=500.0, n_frames=ev_frames)
    mesh.save_npz(out, cam_to_world=np.array(cams), traj_cam_to_world=np.array(traj), traj_t=times)
    print(f"wrote {out}: {len(mesh.faces)} triangles, {len(mesh.instances)} defects, {len(cams)} poses, "
          f"{len(traj)}-frame trajectory")


def npz_materials(z) -> list[dict]:
    """The material table of a ``RenderMesh.save_npz`` file as the kernels take it (no roadtwin)."""
    info = json.loads(bytes(z["info"]).decode())
    return [{"name": m["name"], "diffuse": z[f"mat{k}_diffuse"], "roughness": z[f"mat{k}_roughness"],
             "normal": z[f"mat{k}_normal"] if m["normal"] else None, "metallic": m["metallic"],
             "wrap": tuple(m["wrap"])} for k, m in enumerate(info["materials"])]


def bench(npz: Path, device: str | None, width: int, height: int, frames: int, ev_size: tuple[int, int],
          baseline: float = 0.54, hfov: float = 90.0, save: Path | None = None) -> dict:
    import roadtwin_core.render.events as ev
    import roadtwin_warp_render.raycast as rc
    import warp as wp

    wp.config.log_level = max(wp.config.log_level, 30)
    z = np.load(npz)
    v = z["vertices"].astype(np.float64)
    origin = np.floor((v.min(0) + v.max(0)) / 2)
    t0 = time.perf_counter()
    rs = rc.RaycastScene(v - origin, z["faces"], z["face_class"], z["face_instance"], z["face_material"],
                         z["face_uv"], npz_materials(z), device=device)
    rs.synchronize()
    t_build = time.perf_counter() - t0
    light = rc.make_light(rc.light_preset("clear"))

    def cam_of(m, w, h):
        f = 0.5 * w / math.tan(math.radians(hfov) / 2)
        m = np.array(m, dtype=np.float64)
        m[:3, 3] -= origin
        return rc.make_cam(f, f, (w - 1) / 2, (h - 1) / 2, w, h, m)

    cams = [cam_of(m, width, height) for m in z["cam_to_world"]]

    def timed(fn, n):
        fn(cams[0])  # compile / warm up
        rs.synchronize()
        t = time.perf_counter()
        for k in range(n):
            fn(cams[k % len(cams)])
        rs.synchronize()
        return n / (time.perf_counter() - t)

    gb = rs.buffer(width, height)
    gbr = rs.buffer(width, height, 1)
    res = {"device": str(rs.device), "triangles": int(len(z["faces"])), "size": f"{width}x{height}",
           "materials": len(npz_materials(z)), "texels": int(rs.texels), "mesh_build_s": round(t_build, 3)}
    res["gbuffer_fps"] = timed(lambda c: rs.gbuffer(c, gb), frames)
    res["rgb_fps"] = timed(lambda c: rs.shade(c, light, rs.gbuffer(c, gb)), frames)

    def stereo(c):
        rs.shade(c, light, rs.gbuffer(c, gb))
        rot = np.array(c.rot, dtype=np.float64).reshape(3, 3)
        right = np.array(c.pos, dtype=np.float64) + baseline * rot[:, 0]
        rs.stereo(c, right, baseline, gb)
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = rot, right
        cr = rc.make_cam(c.fx, c.fy, c.cx, c.cy, c.width, c.height, m)
        rs.shade(cr, light, rs.gbuffer(cr, gbr))

    res["stereo_rgb_fps"] = timed(stereo, max(2, frames // 2))
    if save:  # the first pose's G-buffer and RGB, to compare devices
        rs.shade(cams[0], light, rs.gbuffer(cams[0], gb))
        np.savez_compressed(save, **gb.numpy(("depth", "normal", "cls", "inst", "face", "rgb")))
    if not rs.device.is_cuda:
        try:
            rs.enable_open3d()
        except ImportError:
            res["open3d"] = "not installed"
        else:
            res["gbuffer_open3d_fps"] = timed(lambda c: rs.gbuffer_open3d(c, gb), frames)
            res["rgb_open3d_fps"] = timed(lambda c: rs.shade(c, light, rs.gbuffer_open3d(c, gb)), frames)

    # events: render the drive, then time the simulator alone
    ew, eh = ev_size
    traj = [cam_of(m, ew, eh) for m in z["traj_cam_to_world"]]
    times = z["traj_t"]
    gbe = rs.buffer(ew, eh, 2)
    t = time.perf_counter()
    imgs = []
    for c in traj:
        rs.shade(c, light, rs.gbuffer(c, gbe))
        imgs.append(gbe.rgb.numpy().reshape(eh, ew, 3).copy())
    t_render = time.perf_counter() - t
    sim = ev.EventSimulator(ew, eh, seed=0)
    t = time.perf_counter()
    n = 0
    for img, tt in zip(imgs, times):
        n += len(sim.step(img, float(tt))["t"])
    t_sim = time.perf_counter() - t
    res.update({"events_size": f"{ew}x{eh}", "events_frames": len(imgs), "events": n,
                "events_render_fps": len(imgs) / t_render, "events_sim_fps": len(imgs) / t_sim,
                "events_per_s": n / t_sim})
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prepare", type=Path, help="write the benchmark .npz and stop")
    ap.add_argument("--stage", type=Path, help="composed stage for --prepare (default: compose stages/town.usda)")
    ap.add_argument("--mesh", type=Path, help="benchmark .npz from --prepare")
    ap.add_argument("--device", default=None, help="warp device: cpu, cuda, cuda:N (default: warp's preferred)")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--frames", type=int, default=10, help="timed frames per figure")
    ap.add_argument("--poses", type=int, default=16)
    ap.add_argument("--event-size", default="320x240")
    ap.add_argument("--event-frames", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--save", type=Path, help="save the first pose's G-buffer and RGB (.npz) to compare devices")
    args = ap.parse_args()
    if args.prepare:
        prepare(args.prepare, args.stage, args.poses, args.seed, args.event_frames)
        return
    tmp = None
    npz = args.mesh
    if npz is None:
        tmp = tempfile.TemporaryDirectory()
        npz = Path(tmp.name) / "town.npz"
        prepare(npz, args.stage, args.poses, args.seed, args.event_frames)
    w, h = (int(x) for x in args.size.lower().split("x"))
    ew, eh = (int(x) for x in args.event_size.lower().split("x"))
    res = bench(npz, args.device, w, h, args.frames, (ew, eh), save=args.save)
    res["machine"] = f"{platform.machine()} {platform.processor() or ''}".strip()
    for k, v in res.items():
        print(f"{k:>20}: {v:.2f}" if isinstance(v, float) else f"{k:>20}: {v}")
    print("BENCH " + json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in res.items()}))
    if tmp:
        tmp.cleanup()


if __name__ == "__main__":
    main()
