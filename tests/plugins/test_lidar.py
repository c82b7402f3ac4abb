"""LiDAR surface reconstructor (issue 4, coarse stream) against simulated ground truth.

A Livox-like rosette LiDAR (10 frames, 2 cm range noise, 5 % dropouts) scans an ISO 8608 class C
road with a 5 cm pothole; the reconstruction is compared with the ground-truth mesh.
"""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

from roadtwin_core import RoadtwinError
from roadtwin_core.plugins import PluginManager
from roadtwin_core.render import camera_matrix

pytest.importorskip("open3d")

ROOT = Path(__file__).resolve().parents[2]


def _plugin(name: str):
    try:
        return importlib.import_module(name)
    except ImportError:  # editable install made before the plugin existed
        sys.path.insert(0, str(ROOT / "plugins"))
        return importlib.import_module(name)


rl = _plugin("roadtwin_lidar")
rs = _plugin("roadtwin_sensors")  # the rosette scan simulator: a sensor model (issue 20)
from roadtwin_lidar.simulate import evaluate_surface  # noqa: E402

# Measured 2026-11-21 (bench/lidar.py, seeds 0-7): vertex RMSE 2.2-2.3 mm, grid RMSE 1.6-1.8 mm
# (target <= 5 mm); pothole depth recovered 1.3-4.8 mm too shallow (seed 0, used here: 2.2 mm).
# Floors: 4 mm RMSE (margin to the target), 5 mm depth.
RMSE_FLOOR_M = 0.004
DEPTH_TOL_M = 0.005
CENTER, RADIUS, DEPTH = (1.35, 0.2), 0.35, 0.05


@pytest.fixture(scope="module")
def lidar():
    pm = PluginManager(load_entry_points=False)
    pm.register(rl, name="lidar")
    return pm.get("reconstructors", "lidar_surface")


@pytest.fixture(scope="module")
def scene():
    v, f, height = rl.pothole_road_mesh(road_class="C", seed=0, pothole_center=CENTER, pothole_radius_m=RADIUS,
                                        pothole_depth_m=DEPTH)
    frames, poses = rs.simulate_scans(v, f, rs.path_poses(10, seed=0), rs.RosetteScanner(range_sigma_m=0.02),
                                      seed=100)
    return v, f, frames, poses


@pytest.fixture(scope="module")
def saved(scene, tmp_path_factory):
    _, _, frames, poses = scene
    return rl.save_frames(tmp_path_factory.mktemp("frames"), frames, poses, fmt="npz", pose_format="kitti")


@pytest.fixture(scope="module")
def surface(lidar, saved):
    paths, pose_path = saved
    return lidar.run({"frames": paths, "poses": pose_path})


def test_registered(lidar):
    assert lidar.name == "lidar_surface" and lidar.produces == "surface" and lidar.description


def test_rosette_is_non_repetitive_and_fills_fov():
    sc = rs.RosetteScanner()
    d0 = rs.rosette_directions(2000, 0.0, 0.1, sc.fov_deg, sc.f1_hz, sc.f2_hz)
    d1 = rs.rosette_directions(2000, 0.1, 0.1, sc.fov_deg, sc.f1_hz, sc.f2_hz)
    np.testing.assert_allclose(np.linalg.norm(d0, axis=1), 1.0)
    half = np.degrees(np.arccos(np.clip(d0[:, 2], -1, 1)))
    assert half.max() <= sc.fov_deg / 2 + 1e-6 and half.max() > 0.9 * sc.fov_deg / 2 and half.min() < 5
    assert np.abs(d0 - d1).max() > 0.1  # the next frame does not repeat the pattern


def test_simulated_frames(scene):
    _, _, frames, poses = scene
    assert len(frames) == 10 and poses.shape == (10, 4, 4)
    n = [len(x) for x in frames]
    assert min(n) > 0.9 * 0.95 * rs.RosetteScanner().points_per_frame  # ~5 % dropouts
    r = np.linalg.norm(frames[0], axis=1)
    assert 1.5 < r.min() and r.max() < 2.6  # 1.8 m above the road, 35 deg half FOV


def test_height_rmse_and_pothole_depth(surface, scene):
    v, f, _, _ = scene
    assert surface.vertices[:, 2].std() < 0.05  # ground plane at z = 0 after alignment
    r = evaluate_surface(surface.world_vertices(), surface.faces, v, f, pothole_center=CENTER,
                         pothole_radius_m=RADIUS)
    print(r)
    assert r["covered_m2"] > 10.0
    assert r["vertex_rmse_m"] <= RMSE_FLOOR_M, r
    assert r["grid_rmse_m"] <= RMSE_FLOOR_M, r
    assert abs(r["pothole_depth_rec_m"] - r["pothole_depth_gt_m"]) <= DEPTH_TOL_M, r
    assert abs(r["pothole_depth_gt_m"] - DEPTH) < 0.01


def test_tum_poses_ply_frames_match(lidar, scene, tmp_path):
    _, _, frames, poses = scene
    paths, pose_path = rl.save_frames(tmp_path, frames[:3], poses[:3], fmt="ply", pose_format="tum")
    got = rl.load_poses(pose_path)
    np.testing.assert_allclose(got, poses[:3], atol=1e-6)
    pts, labels = rl.load_frame(paths[0])
    assert labels is None and np.allclose(pts, frames[0], atol=1e-6)


def test_local_heights_plane_and_quadric():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.2, 0.2, (4000, 2))
    plane = np.column_stack([xy, 0.01 + 0.1 * xy[:, 0] - 0.05 * xy[:, 1]])
    q = np.array([[0.0, 0.0], [0.05, -0.03]])
    z, n = rl.local_heights(plane, q, 0.08, 256, 8)
    np.testing.assert_allclose(z, 0.01 + 0.1 * q[:, 0] - 0.05 * q[:, 1], atol=1e-9)
    bowl = np.column_stack([xy, (xy**2).sum(1)])  # curvature 2 /m
    zp, _ = rl.local_heights(bowl, q[:1], 0.08, 4000, 8)
    zq, _ = rl.local_heights(bowl, q[:1], 0.08, 4000, 8, curvature_prior=100.0)
    assert 0.001 < zp[0] < 0.005 and abs(zq[0]) < 1e-6  # the plane flattens the bowl, the quadric does not
    few, _ = rl.local_heights(plane, np.array([[5.0, 5.0]]), 0.08, 256, 8)
    assert np.isnan(few[0])


def test_ply_labels(tmp_path):
    import open3d as o3d

    pts = np.random.default_rng(1).uniform(0, 1, (50, 3)).astype(np.float32)
    pc = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts))
    pc.point["label"] = o3d.core.Tensor(np.r_[np.full(25, 40), np.full(25, 10)].astype(np.int32)[:, None])
    path = tmp_path / "lab.ply"
    assert o3d.t.io.write_point_cloud(str(path), pc)
    got, labels = rl.load_frame(path)
    assert len(got) == 50 and labels is not None and (labels == 40).sum() == 25


def test_single_frame_world_and_labels(lidar, scene):
    _, _, frames, poses = scene
    world = frames[0] @ poses[0][:3, :3].T + poses[0][:3, 3]
    junk = world[:500] + [0.0, 0.0, 0.5]  # non-road points half a metre up
    pts = np.vstack([world, junk])
    labels = np.r_[np.full(len(world), 40), np.full(len(junk), 50)]
    clean = lidar.run({"frames": [pts], "labels": [labels]})
    assert np.abs(clean.vertices[:, 2]).max() < 0.1
    with pytest.raises(RoadtwinError, match="no road points"):
        lidar.run({"frames": [pts], "labels": [labels], "road_labels": [7]})


def test_write_and_read_asset(surface, tmp_path):
    from pxr import Usd, UsdGeom

    path = rl.write_surface_asset(surface, tmp_path / "road.usda")
    stage = Usd.Stage.Open(str(path))
    root = stage.GetDefaultPrim()
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert Usd.ModelAPI(root).GetKind() == "component"
    assert root.GetAttribute("roadtwin:source").Get()
    back = rl.read_surface_asset(path)
    assert len(back.faces) == len(surface.faces)
    np.testing.assert_allclose(back.vertices, surface.vertices, atol=1e-5)
    np.testing.assert_allclose(back.alignment, surface.alignment, atol=1e-12)
    xy = surface.vertices[::50, :2]
    np.testing.assert_allclose(back.height(xy), surface.vertices[::50, 2], atol=1e-4)
    assert not list(tmp_path.glob(".*tmp*"))


def test_bad_input(lidar, saved, tmp_path):
    paths, pose_path = saved
    empty = tmp_path / "empty.npz"
    np.savez(empty, points=np.zeros((0, 3)))
    with pytest.raises(RoadtwinError, match="empty.npz: empty point cloud"):
        lidar.run({"frames": [empty]})
    nan = tmp_path / "nan.npz"
    np.savez(nan, points=np.full((10, 3), np.nan))
    with pytest.raises(RoadtwinError, match="nan.npz: no finite points"):
        lidar.run({"frames": [nan]})
    with pytest.raises(RoadtwinError, match=r"poses.txt: 10 poses for 3 frames"):
        lidar.run({"frames": paths[:3], "poses": pose_path})
    with pytest.raises(RoadtwinError, match="need a pose file"):
        lidar.run({"frames": paths[:2]})
    bad = tmp_path / "bad_poses.txt"
    bad.write_text("1 2 3\n")
    with pytest.raises(RoadtwinError, match="bad_poses.txt:1: expected 12 numbers"):
        lidar.run({"frames": paths[:1], "poses": bad})
    with pytest.raises(RoadtwinError) as exc:
        lidar.run({"frames": [tmp_path / "missing.ply"]})
    assert str(exc.value) == f"{tmp_path / 'missing.ply'}: no such point cloud file"


def test_cli_reconstruct_surface(monkeypatch, saved, tmp_path):
    import typer
    from typer.testing import CliRunner

    from roadtwin_core import plugins as plugins_mod
    from roadtwin_core.cli.reconstruct import reconstruct_app

    pm = PluginManager(load_entry_points=False)
    pm.register(rl, name="lidar")
    monkeypatch.setattr(plugins_mod, "_manager", pm)
    app = typer.Typer()
    app.add_typer(reconstruct_app, name="reconstruct")
    paths, pose_path = saved
    out = tmp_path / "surface.usda"
    res = CliRunner().invoke(app, ["reconstruct", "surface", *map(str, paths), "--poses", str(pose_path),
                                   "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert out.exists() and "vertices" in res.output
    # Bad input: one clear error, nothing written.
    bad_out = tmp_path / "bad.usda"
    res = CliRunner().invoke(app, ["reconstruct", "surface", *map(str, paths[:3]), "--poses", str(pose_path),
                                   "-o", str(bad_out)])
    assert res.exit_code != 0
    assert isinstance(res.exception, RoadtwinError) and "10 poses for 3 frames" in str(res.exception)
    assert "\n" not in str(res.exception)
    assert not bad_out.exists() and not list(tmp_path.glob(".*tmp*"))


# ---------------------------------------------------------------- semantic masks (Grounded-SAM stand-in)
EDGE_Y = 0.8      # road for y < EDGE_Y; a sidewalk raised by CURB_M beyond it
CURB_M = 0.15
CAM_K = (300.0, 300.0, 320.0, 240.0)
CAM_SIZE = (480, 640)


def _cam_from_lidar() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [2.0, -1.5, 1.0], degrees=True).as_matrix()
    T[:3, 3] = [0.10, -0.05, 0.02]
    return T


def _road_masks(poses: np.ndarray, T_cl: np.ndarray) -> list[np.ndarray]:
    """The true road polygon (z = 0) projected into the camera of every frame."""
    import cv2

    fx, fy, cx, cy = CAM_K
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    poly = np.array([[-2.0, -2.0, 0.0], [5.0, -2.0, 0.0], [5.0, EDGE_Y, 0.0], [-2.0, EDGE_Y, 0.0]])
    masks = []
    for P in poses:
        M = T_cl @ np.linalg.inv(P)
        pc = poly @ M[:3, :3].T + M[:3, 3]
        assert (pc[:, 2] > 0).all()
        uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
        m = np.zeros(CAM_SIZE, np.uint8)
        cv2.fillPoly(m, [np.round(uv).astype(np.int32)], 255)
        masks.append(m)
    return masks


@pytest.fixture(scope="module")
def curb_scene(scene, tmp_path_factory):
    """The class-C road of ``scene`` with a 15 cm raised sidewalk at y > EDGE_Y, scanned, plus road
    masks of a camera beside the LiDAR, all saved as files."""
    import cv2

    v, f, _, _ = scene
    vc = v.copy()
    vc[vc[:, 1] > EDGE_Y + 1e-6, 2] += CURB_M
    frames, poses = rs.simulate_scans(vc, f, rs.path_poses(10, seed=0), rs.RosetteScanner(range_sigma_m=0.02),
                                      seed=100)
    folder = tmp_path_factory.mktemp("curb")
    paths, pose_path = rl.save_frames(folder / "frames", frames, poses, fmt="npz", pose_format="kitti")
    T_cl = _cam_from_lidar()
    (folder / "masks").mkdir()
    mask_paths = []
    for i, m in enumerate(_road_masks(poses, T_cl)):
        mp = folder / "masks" / f"mask_{i:03d}.png"
        assert cv2.imwrite(str(mp), m)
        mask_paths.append(mp)
    ext = folder / "cam_from_lidar.txt"
    np.savetxt(ext, T_cl)
    return {"paths": paths, "poses": pose_path, "masks": mask_paths, "ext": ext, "T": T_cl, "frames": frames,
            "folder": folder}


def test_mask_road_points_projection():
    K = camera_matrix((100.0, 100.0, 2.0, 1.0))
    mask = np.zeros((3, 5), bool)
    mask[1, 3] = True
    pts = np.array([[0.01, 0.0, 1.0],    # u = 3, v = 1: road
                    [0.0, 0.0, 1.0],     # u = 2: not road
                    [-0.01, 0.0, -1.0],  # behind the camera (would project onto u = 3)
                    [1.0, 0.0, 1.0]])    # outside the image
    np.testing.assert_array_equal(rl.mask_road_points(pts, mask, K, np.eye(4)), [True, False, False, False])


def test_masks_exclude_raised_sidewalk(lidar, scene, curb_scene):
    v, f, _, _ = scene
    c = curb_scene
    masked = lidar.run({"frames": c["paths"], "poses": c["poses"], "masks": c["masks"], "K": CAM_K,
                        "cam_from_lidar": c["ext"]})
    wv = masked.world_vertices()
    # Kept points reach ~2 cm past the edge (range noise along oblique rays; the 2 cm GT ramp).
    assert wv[:, 1].max() < EDGE_Y + 0.05, wv[:, 1].max()  # no vertex on the sidewalk
    near = wv[:, 1] > EDGE_Y - 0.2
    assert near.sum() > 50 and np.abs(wv[near, 2]).max() < 0.05  # the road by the curb stays at road level
    r = evaluate_surface(wv, masked.faces, v, f)  # the ground truth without the sidewalk
    print(r)
    assert r["vertex_rmse_m"] <= RMSE_FLOOR_M, r
    assert r["grid_rmse_m"] <= RMSE_FLOOR_M, r
    # Control: without the masks the sidewalk is reconstructed (so the masks did the work above).
    plain = lidar.run({"frames": c["paths"], "poses": c["poses"]}).world_vertices()
    side = plain[:, 1] > EDGE_Y + 0.05
    assert side.sum() > 50 and np.median(plain[side, 2]) > 0.1


def test_masks_bad_input(lidar, curb_scene, tmp_path):
    c = curb_scene
    base = {"frames": c["paths"][:2], "poses": rl.load_poses(c["poses"])[:2], "masks": c["masks"][:2],
            "K": CAM_K, "cam_from_lidar": c["T"]}
    with pytest.raises(RoadtwinError, match="1 masks for 2 frames"):
        lidar.run({**base, "masks": c["masks"][:1]})
    with pytest.raises(RoadtwinError, match="intrinsics K"):
        lidar.run({**base, "K": None})
    with pytest.raises(RoadtwinError, match="extrinsic"):
        lidar.run({**base, "cam_from_lidar": None})
    bad_ext = tmp_path / "ext.txt"
    bad_ext.write_text("1 0 0\n0 1 0\n")
    with pytest.raises(RoadtwinError, match="ext.txt: the camera-from-LiDAR extrinsic must be a 4x4"):
        lidar.run({**base, "cam_from_lidar": bad_ext})
    # A frame with no road: its mask is empty.
    empty = np.zeros(CAM_SIZE, np.uint8)
    with pytest.raises(RoadtwinError) as exc:
        lidar.run({**base, "masks": [c["masks"][0], empty]})
    assert str(exc.value).startswith(f"{c['paths'][1]}: no road points") and "\n" not in str(exc.value)
    # A camera looking the other way: every point is behind it.
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    with pytest.raises(RoadtwinError, match="frame_000.npz: no road points"):
        lidar.run({**base, "cam_from_lidar": flip})


def test_cli_reconstruct_surface_masks(monkeypatch, curb_scene, tmp_path):
    import typer
    from typer.testing import CliRunner

    from roadtwin_core import plugins as plugins_mod
    from roadtwin_core.cli.reconstruct import reconstruct_app

    pm = PluginManager(load_entry_points=False)
    pm.register(rl, name="lidar")
    monkeypatch.setattr(plugins_mod, "_manager", pm)
    app = typer.Typer()
    app.add_typer(reconstruct_app, name="reconstruct")
    c = curb_scene
    k = ",".join(str(x) for x in CAM_K)
    common = [*map(str, c["paths"]), "--poses", str(c["poses"])]
    out = tmp_path / "surface.usda"
    res = CliRunner().invoke(app, ["reconstruct", "surface", *common, "--masks", str(c["folder"] / "masks"),
                                   "--K", k, "--cam-from-lidar", str(c["ext"]), "-o", str(out)])
    assert res.exit_code == 0, res.output
    wv = rl.read_surface_asset(out).world_vertices()
    assert wv[:, 1].max() < EDGE_Y + 0.05
    bad_out = tmp_path / "bad.usda"
    for extra, msg in [(["--masks", str(c["masks"][0]), "--K", k, "--cam-from-lidar", str(c["ext"])],
                        "1 masks for 10 frames"),
                       (["--masks", str(c["folder"] / "masks"), "--cam-from-lidar", str(c["ext"])], "--K"),
                       (["--masks", str(c["folder"] / "masks"), "--K", k], "--cam-from-lidar")]:
        res = CliRunner().invoke(app, ["reconstruct", "surface", *common, *extra, "-o", str(bad_out)])
        assert res.exit_code != 0
        assert isinstance(res.exception, RoadtwinError) and msg in str(res.exception), res.exception
        assert "\n" not in str(res.exception)
    assert not bad_out.exists() and not list(tmp_path.glob(".*tmp*"))
