"""``roadtwin reconstruct defects``: stereo defect reconstruction (the paper's fine stream);
``roadtwin reconstruct surface``: LiDAR road surface reconstruction (the coarse stream);
``roadtwin reconstruct photos``: labelled road photos -> textured defect library assets;
``roadtwin reconstruct photo-surfaces``: labelled road photos -> seamless road materials.

Options only: the text options are parsed here into the typed inputs of
:mod:`roadtwin_core.apps.reconstruct`, which checks them and runs the reconstructor plugins
(``stereo_defects``, ``lidar_surface``, ``photo_defects``, ``photo_surfaces``). Bad input raises :class:`~roadtwin_core.RoadtwinError`,
printed by ``roadtwin``'s ``main`` as one line (exit 2), and nothing is written.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from .._console import console, err_console
from ..errors import RoadtwinError
from ..params import PARAM_HELP, parse_param_options

__all__ = ["reconstruct_app", "reconstruct_defects_command", "reconstruct_photo_surfaces_command",
           "reconstruct_photos_command", "reconstruct_surface_command"]

reconstruct_app = typer.Typer(help="Real sensor data -> road surface and defect models.", no_args_is_help=True)


def _reconstructor_option(default: str) -> Any:
    return typer.Option(default, "--reconstructor", help="reconstructor plugin")


def _param_option() -> Any:
    return typer.Option(None, "--param", help=f"reconstructor {PARAM_HELP}")


def _license_option(what: str) -> Any:
    return typer.Option(None, "--license", help=f"license recorded on every {what} (default: the first line of a "
                        "LICENSE file beside the photos)")


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
def reconstruct_defects_command(
    disparity: Optional[Path] = typer.Option(None, "--disparity", "-d", help="disparity map (16-bit PNG, .npy, .pfm)"),
    left: Optional[Path] = typer.Option(None, "--left", help="rectified left image (with --right: SGBM disparity)"),
    right: Optional[Path] = typer.Option(None, "--right", help="rectified right image"),
    K: Optional[str] = typer.Option(None, "--K", help="intrinsics: fx,fy,cx,cy or the 9 entries of K (pixels)"),
    baseline: Optional[float] = typer.Option(None, "--baseline", help="stereo baseline in m"),
    transformed: bool = typer.Option(False, "--transformed", help="the disparity map is already transformed "
                                     "(Fan et al.): detect defect pixels only"),
    disparity_scale: float = typer.Option(1.0, "--disparity-scale", help="integer PNG disparity = value / scale (KITTI: 256)"),
    grid: float = typer.Option(0.01, "--grid", help="mesh grid step in m"),
    road_mask: Optional[Path] = typer.Option(None, "--road-mask", help="road mask image, the disparity's size "
                                             "(nonzero = road): pixels off it are neither road nor defect"),
    out: Path = typer.Option(..., "-o", "--out", help="output folder (replaced atomically): one defect asset per "
                             "instance, mask.png, instances.json"),
    reconstructor: str = _reconstructor_option("stereo_defects"),
    param: Optional[list[str]] = _param_option(),
) -> None:
    """Stereo pair or disparity map -> defect library assets and mask.png."""
    from ..apps.reconstruct import DefectInputs, reconstruct_defects

    inputs = DefectInputs(disparity=disparity, left=left, right=right, K=_floats(K, (4, 9), "--K"),
                          baseline=baseline, transformed=transformed, road_mask=road_mask)
    done = reconstruct_defects(inputs, out, reconstructor=reconstructor, disparity_scale=disparity_scale, grid_m=grid,
                               params=parse_param_options(param))
    result = done.result
    console.print(f"wrote {out}: {int(result.labels.max())} defect instance(s), {len(done.paths)} asset(s), mask.png")
    for m in result.models:
        a = m.attributes()
        console.print(f"  {m.name}: depth {a['depthM'] * 100:.1f} cm, area {a['areaM2']:.3f} m2, "
                      f"volume {a['volumeM3'] * 1000:.2f} L")


@reconstruct_app.command("surface")
def reconstruct_surface_command(
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
    reconstructor: str = _reconstructor_option("lidar_surface"),
    param: Optional[list[str]] = _param_option(),
) -> None:
    """LiDAR frames + poses -> road surface library asset (coarse stream).

    With --masks, each frame's points are projected into its mask (camera --K, --cam-from-lidar)
    and only those landing on a road pixel are kept; points behind the camera or outside the
    image are dropped, and a frame with no road point left is an error naming it."""
    from ..apps.reconstruct import SurfaceInputs, reconstruct_surface

    inputs = SurfaceInputs(frames=list(frames), poses=poses, road_labels=_road_labels(road_labels),
                           masks=masks or None, K=_floats(K, (4,), "--K"), cam_from_lidar=cam_from_lidar)
    done = reconstruct_surface(inputs, out, reconstructor=reconstructor, voxel_m=voxel, radius_m=radius,
                               align=not no_align, params=parse_param_options(param))
    vertices, faces = done.surface.vertices, done.surface.faces
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    console.print(f"wrote {done.path}: {len(vertices)} vertices, {len(faces)} triangles, "
                  f"{hi[0] - lo[0]:.2f} x {hi[1] - lo[1]:.2f} m, z {lo[2]:+.3f}..{hi[2]:+.3f} m "
                  f"from {len(frames)} frame(s)")


def _road_labels(text: str) -> list[int] | None:
    """``--road-labels``: label values (integers), or None for 'all' (every point is road)."""
    if text.strip().lower() in ("", "all", "none"):
        return None
    values = _floats(text, tuple(range(1, 257)), "--road-labels")
    if not all(math.isfinite(v) and v == int(v) and 0 <= v < 2**32 for v in values):
        raise RoadtwinError(f"--road-labels: label values are integers in 0..{2**32 - 1}, got {text!r}")
    return [int(v) for v in values]


def _images_argument() -> Any:
    return typer.Argument(..., help="photos (files, or folders of .jpg/.png)")


def _labels_option() -> Any:
    return typer.Option(..., "--labels", help="label folder: <image stem>.png, one class id per pixel")


def _run_photo_command(run: Callable[..., Any], images: list[Path], labels: Path, classmap: str, rig: str,
                       license_text: Optional[str], out: Path, reconstructor: str, param: Optional[list[str]],
                       *, progress: bool = False) -> Any:
    """What ``photos`` and ``photo-surfaces`` share: the typed :class:`PhotoInputs` from their
    options, then ``run`` (with a frames bar when ``progress``: ``run`` reports over the frames)."""
    from ..apps.reconstruct import PhotoInputs

    preset, overrides = _rig_spec(rig)
    inputs = PhotoInputs(images=list(images), labels=labels, classmap=classmap, rig=preset, rig_overrides=overrides,
                         license=license_text)
    if not progress:
        return run(inputs, out, reconstructor=reconstructor, params=parse_param_options(param))
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err_console, transient=True, disable=not err_console.is_terminal) as bar:
        task = bar.add_task("frames", total=None)
        return run(inputs, out, reconstructor=reconstructor, params=parse_param_options(param),
                   progress=lambda n, total: bar.update(task, completed=n, total=total))


@reconstruct_app.command("photos")
def reconstruct_photos_command(
    images: list[Path] = _images_argument(),
    labels: Path = _labels_option(),
    classmap: str = typer.Option("builtin:road_defects_br", "--classmap", help="class map of the labels: a TOML "
                                 "file or builtin:NAME (its classes filled from a defect type are reconstructed)"),
    rig: str = typer.Option("survey", "--rig", help="camera rig preset, optionally with overrides: "
                            "survey:pitch=-24,height=2.4,roll=0,hfov=60 (also width, height_px: the size the "
                            "rig is given at)"),
    license_text: Optional[str] = _license_option("asset"),
    out: Path = typer.Option(..., "-o", "--out", help="library folder (replaced atomically): NAME.usda + "
                             "NAME.geom.usda per instance, textures/, instances.json"),
    reconstructor: str = _reconstructor_option("photo_defects"),
    param: Optional[list[str]] = _param_option(),
) -> None:
    """Labelled photos -> textured defect library assets (back-projected through the rig onto the road)."""
    from ..apps.reconstruct import reconstruct_photos

    done = _run_photo_command(reconstruct_photos, images, labels, classmap, rig, license_text, out, reconstructor,
                              param)
    by_type: dict[str, int] = {}
    for m in done.result.models:
        by_type[m.defect_type] = by_type.get(m.defect_type, 0) + 1
    console.print(f"wrote {out}: {len(done.paths)} asset(s) from {done.photos} photo(s) "
                  f"({', '.join(f'{n} {t}' for t, n in sorted(by_type.items()))}); "
                  f"{len(done.result.skipped)} instance(s) skipped (smaller than min_pixels or min_area_m2)")


@reconstruct_app.command("photo-surfaces")
def reconstruct_photo_surfaces_command(
    images: list[Path] = _images_argument(),
    labels: Path = _labels_option(),
    classmap: str = typer.Option("builtin:road_defects_br", "--classmap", help="class map of the labels: its road "
                                 "class is cut from, its defect classes are kept away from"),
    rig: str = typer.Option("survey", "--rig", help="camera rig preset, optionally with overrides (as for "
                            "reconstruct photos)"),
    license_text: Optional[str] = _license_option("material"),
    out: Path = typer.Option(..., "-o", "--out", help="materials folder (replaced atomically): NAME_diffuse.png, "
                             "NAME_roughness.png, NAME_normal.png per surface, materials.json"),
    reconstructor: str = _reconstructor_option("photo_surfaces"),
    param: Optional[list[str]] = _param_option(),
) -> None:
    """Labelled photos -> seamless asphalt materials cut from their defect-free road (compose --road-textures)."""
    from ..apps.reconstruct import reconstruct_photo_surfaces

    done = _run_photo_command(reconstruct_photo_surfaces, images, labels, classmap, rig, license_text, out,
                              reconstructor, param, progress=True)
    result = done.result
    console.print(f"wrote {out}: {len(result.surfaces)} surface(s) from {done.photos} photo(s) "
                  f"({len(result.skipped)} without a clean window)")
    for s in result.surfaces:
        r = s.record
        made = (f"{len(r['sources'])} window(s) quilted, its own {r['window_m']:g} m" if r.get("sources")
                else f"{r['window_m']:g} m window x{r['repeats']}")
        console.print(f"  {s.name}: {made} from {Path(r['frame']).name}, "
                      f"seam ratio {max(r['seam_ratio'].values()):.2f} "
                      f"(unblended {max(r['seam_ratio_unblended'].values()):.1f})")


def _rig_spec(text: str) -> tuple[str, dict[str, float]]:
    """``--rig``: ``PRESET`` or ``PRESET:key=value,...`` -> (preset, {key: number})."""
    name, _, rest = text.partition(":")
    overrides: dict[str, float] = {}
    for item in filter(None, (x.strip() for x in rest.split(","))):
        key, eq, value = (x.strip() for x in item.partition("="))
        try:
            if not eq:
                raise ValueError
            overrides[key] = float(value)
        except ValueError:
            raise RoadtwinError(f"--rig: expected key=number in {text!r}, got {item!r}") from None
    return name.strip(), overrides
