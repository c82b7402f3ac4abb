"""``roadtwin reconstruct defects``: stereo defect reconstruction (the paper's fine stream);
``roadtwin reconstruct surface``: LiDAR road surface reconstruction (the coarse stream).

Registered in :mod:`roadtwin_core.cli` with ``app.add_typer(reconstruct_app, name="reconstruct")``.
The work is done by the reconstructor plugins named ``stereo_defects`` and ``lidar_surface``,
asked for through the plugin manager (the core never imports a plugin). Bad input raises
:class:`~roadtwin_core.RoadtwinError`, printed by ``roadtwin``'s ``main`` as one line (exit 2),
and nothing is written.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np
import typer
from .._console import console

from ..errors import RoadtwinError
from ..params import PARAM_HELP, cli_params


reconstruct_app = typer.Typer(help="Real sensor data -> road surface and defect models.", no_args_is_help=True)


def _floats(text: Optional[str], n: tuple[int, ...], what: str) -> Optional[list[float]]:
    if text is None:
        return None
    try:
        vals = [float(x) for x in text.replace(";", ",").split(",") if x.strip()]
    except ValueError:
        raise RoadtwinError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if len(vals) not in n:
        raise RoadtwinError(f"{what}: expected {' or '.join(map(str, n))} numbers, got {len(vals)}")
    return vals


@reconstruct_app.command("defects")
def reconstruct_defects(
    disparity: Optional[Path] = typer.Option(None, "--disparity", "-d", help="disparity map (16-bit PNG, .npy, .pfm)"),
    left: Optional[Path] = typer.Option(None, "--left", help="rectified left image (with --right: SGBM disparity)"),
    right: Optional[Path] = typer.Option(None, "--right", help="rectified right image"),
    K: Optional[str] = typer.Option(None, "--K", help="intrinsics: fx,fy,cx,cy or the 9 entries of K (pixels)"),
    baseline: Optional[float] = typer.Option(None, "--baseline", help="stereo baseline in m"),
    transformed: bool = typer.Option(False, "--transformed", help="the disparity map is already transformed "
                                     "(Fan et al.): detect defect pixels only"),
    disparity_scale: float = typer.Option(1.0, "--disparity-scale", help="integer PNG disparity = value / scale (KITTI: 256)"),
    grid: float = typer.Option(0.01, "--grid", help="mesh grid step in m"),
    out: Path = typer.Option(..., "-o", "--out", help="output folder (replaced atomically): one defect asset per "
                             "instance, mask.png, instances.json"),
    reconstructor: str = typer.Option("stereo_defects", "--reconstructor", help="reconstructor plugin"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"reconstructor {PARAM_HELP}"),
) -> None:
    """Stereo pair or disparity map -> defect library assets and mask.png."""
    from ..params import make_params
    from ..plugins import get_plugin_manager

    from ..atomic import output_path

    output_path(out, "dir")
    if disparity is not None and (left is not None or right is not None):
        raise RoadtwinError("give --disparity or --left/--right, not both")
    for p in (disparity, left, right):
        if p is not None and not p.exists():
            raise RoadtwinError(f"{p}: no such file")
    rec = get_plugin_manager().get("reconstructors", reconstructor)
    if rec.produces != "defects":
        raise RoadtwinError(f"reconstructor {reconstructor!r} does not produce defects")
    params = make_params(rec.Params, {"disparity_scale": disparity_scale, "grid_m": grid}, reconstructor)
    params = cli_params(param, params, f"reconstructor {reconstructor}")
    k = _floats(K, (4, 9), "--K")
    inputs = {"disparity": disparity, "left": left, "right": right, "K": k, "baseline": baseline,
              "transformed": transformed}
    result = rec.run(inputs, params)
    paths = rec.write(result, out)
    console.print(f"wrote {out}: {int(result.labels.max())} defect instance(s), {len(paths)} asset(s), mask.png")
    for m in result.models:
        a = m.attributes()
        console.print(f"  {m.name}: depth {a['depthM'] * 100:.1f} cm, area {a['areaM2']:.3f} m2, "
                      f"volume {a['volumeM3'] * 1000:.2f} L")


@reconstruct_app.command("surface")
def reconstruct_surface(
    frames: list[Path] = typer.Argument(..., help="point cloud frames (.ply, .pcd, .npz with 'points' [+ 'labels'], .npy)"),
    poses: Optional[Path] = typer.Option(None, "--poses", "-p", help="per-frame sensor-to-world poses: KITTI (3x4 "
                                         "per line) or TUM (t x y z qx qy qz qw); one frame without = world coordinates"),
    out: Path = typer.Option(..., "-o", "--out", help="surface library asset (.usda), a Z-up mesh in meters"),
    road_labels: str = typer.Option("40,44", "--road-labels", help="label values kept as road in labelled frames "
                                    "(SemanticKITTI road, parking; 'all' keeps every point); frames without labels are all road"),
    voxel: float = typer.Option(0.05, "--voxel", help="vertex spacing (XY voxel size) in m"),
    radius: float = typer.Option(0.08, "--radius", help="elevation fit radius in m"),
    masks: Optional[list[Path]] = typer.Option(None, "--masks", help="per-frame road masks (PNG, non-zero = road): "
                                               "a folder (its images, sorted) or one file per frame (repeat the "
                                               "option), matched to the frames in order; needs --K and --cam-from-lidar"),
    K: Optional[str] = typer.Option(None, "--K", help="mask camera intrinsics fx,fy,cx,cy (pixels)"),
    cam_from_lidar: Optional[Path] = typer.Option(None, "--cam-from-lidar", help="text file with the 4x4 "
                                                  "camera-from-LiDAR transform (one for all frames)"),
    no_align: bool = typer.Option(False, "--no-align", help="keep the input Z (no RANSAC ground plane to Z-up)"),
    reconstructor: str = typer.Option("lidar_surface", "--reconstructor", help="reconstructor plugin"),
    param: Optional[list[str]] = typer.Option(None, "--param", help=f"reconstructor {PARAM_HELP}"),
) -> None:
    """LiDAR frames + poses -> road surface library asset (coarse stream).

    With --masks, each frame's points are projected into its mask (camera --K, --cam-from-lidar)
    and only those landing on a road pixel are kept; points behind the camera or outside the
    image are dropped, and a frame with no road point left is an error naming it."""
    from ..params import make_params
    from ..plugins import get_plugin_manager

    for p in [*frames, *([poses] if poses is not None else []), *(masks or []),
              *([cam_from_lidar] if cam_from_lidar is not None else [])]:
        if not p.exists():
            raise RoadtwinError(f"{p}: no such file")
    mask_files: Optional[list[Path]] = None
    if masks:
        mask_files = []
        for m in masks:
            if m.is_dir():
                found = sorted(q for q in m.iterdir() if q.is_file() and q.suffix.lower() in (".png", ".jpg", ".jpeg",
                                                                                            ".bmp", ".tif", ".tiff"))
                if not found:
                    raise RoadtwinError(f"{m}: no mask images (.png) in the folder")
                mask_files += found
            else:
                mask_files.append(m)
        if len(mask_files) != len(frames):
            raise RoadtwinError(f"--masks: {len(mask_files)} masks for {len(frames)} frames (one mask per frame)")
        if K is None:
            raise RoadtwinError("--masks needs the camera intrinsics --K fx,fy,cx,cy")
        if cam_from_lidar is None:
            raise RoadtwinError("--masks needs the camera-from-LiDAR extrinsic --cam-from-lidar FILE (4x4)")
    elif K is not None or cam_from_lidar is not None:
        raise RoadtwinError("--K and --cam-from-lidar are only used with --masks")
    k = _floats(K, (4,), "--K")
    if out.suffix not in (".usda", ".usd", ".usdc"):
        raise RoadtwinError(f"{out}: the surface asset must be a .usda, .usd or .usdc file")
    from ..atomic import output_path

    output_path(out)
    labels = None
    if road_labels.strip().lower() not in ("", "all", "none"):
        values = _floats(road_labels, tuple(range(1, 257)), "--road-labels")
        if not all(np.isfinite(v) and v == int(v) and 0 <= v < 2**32 for v in values):
            raise RoadtwinError(f"--road-labels: label values are integers in 0..{2**32 - 1}, got {road_labels!r}")
        labels = [int(v) for v in values]
    rec = get_plugin_manager().get("reconstructors", reconstructor)
    if rec.produces != "surface":
        raise RoadtwinError(f"reconstructor {reconstructor!r} does not produce a surface")
    params = make_params(rec.Params, {"voxel_m": voxel, "radius_m": radius, "align": not no_align}, reconstructor)
    params = cli_params(param, params, f"reconstructor {reconstructor}")
    inputs = {"frames": list(frames), "poses": poses, "road_labels": labels}
    if mask_files is not None:
        inputs.update(masks=mask_files, K=k, cam_from_lidar=cam_from_lidar)
    surface = rec.run(inputs, params)
    path = rec.write(surface, out)
    lo, hi = surface.vertices.min(axis=0), surface.vertices.max(axis=0)
    console.print(f"wrote {path}: {len(surface.vertices)} vertices, {len(surface.faces)} triangles, "
                  f"{hi[0] - lo[0]:.2f} x {hi[1] - lo[1]:.2f} m, z {lo[2]:+.3f}..{hi[2]:+.3f} m "
                  f"from {len(frames)} frame(s)")
