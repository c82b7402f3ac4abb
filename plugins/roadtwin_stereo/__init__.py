"""Fine stream of the hierarchical road model creator: stereo defect reconstruction.

Registers the reconstructor ``stereo_defects`` (produces ``"defects"``). The kernels are
core-free (numpy / OpenCV / scipy / triangle / shapely) and can be used on their own:

- :mod:`.transform` -- Fan et al.'s disparity transformation (roll angle + road disparity model),
  OpenCV SGBM disparity from a rectified pair;
- :mod:`.subpixel` -- Lucas-Kanade refinement of SGBM's disparity along the rows (no pixel locking);
- :mod:`.segment` -- defect pixels and instances from a transformed disparity map;
- :mod:`.mesh` -- one instance -> 2.5D mesh in a local road frame (z = 0 on the road);
- :mod:`.texture` -- each defect's footprint pixels from the left image, an orthographic patch in
  its local XY (texture of a textured asset), and raw disparity back from a normalised transformed map;
- :mod:`.fusion` -- several pairs' depth-below-the-road evidence of a drive fused on one pair
  through their poses (:meth:`StereoDefects.run_sequence`);
- :mod:`.synthetic` -- exact disparity of a known bowl pothole, for tests and benchmarks.

Only this module and :mod:`.inputs` (the parameters, the result, reading the inputs) touch
roadtwin_core (:class:`StereoDefects` and its writer: DefectModel, DefectLook, write_defect_asset,
atomic output).

Inputs of ``reconstruct(inputs, params)`` (a dict): ``disparity`` (path to a disparity map, or an
array) *or* ``left`` + ``right`` (rectified pair, paths or arrays); ``K`` (3x3, or fx, fy, cx, cy)
and ``baseline`` (m) -- required for metric models; ``transformed`` (bool: the disparity map is
already transformed, as in ``../shared/data/stereo_pothole``: then only pixels and instances come
out, since a transformed, normalised map has lost the disparity units needed for 3D points);
``source`` (a string recorded on every model; default the input path); ``road_mask`` (optional,
path or array, non-zero = road, e.g. a road segmentation's output: pixels off it are not modelled
as road nor searched for defects); ``rgb`` (optional, path or array: the left colour image of a
disparity map, its size; a pair's ``left`` serves otherwise): with it and ``params.texture`` (the
default) :meth:`StereoDefects.write` gives every asset its footprint's pixels as a decal texture
and a ``roadtwin:source`` naming the frame, the instance and ``license`` (default: the first line
of a LICENSE file beside the image or up to three folders above); ``depth_scale`` (optional dict,
e.g. ``texture.nominal_depth_scale(...)`` for a map rebuilt by ``disparity_from_transformed``):
kept in each model's params, its asset says ``roadtwin:depthScale`` (docs/architecture.md).
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from roadtwin_core import DefectLook, DefectModel, RoadtwinError, check_params, hookimpl
from roadtwin_core.atomic import atomic_output_dir
from roadtwin_core.render import camera_matrix
from roadtwin_core.usd import safe_prim_name, write_defect_asset

from .fusion import FrameFusion, FusionOptions, PairEvidence, fused_residual, fused_sequence, pair_evidence
from .inputs import (StereoDefectsParams, StereoResult, apply_road_mask, pose_of, read_disparity,
                     read_image)
from .mesh import DefectInstance, reconstruct_instance
from .road_model import metric_road_depth
from .segment import (SegmentParams, f1_score, load_disparity, load_label, road_residual, segment_defects,
                      segment_residual)
from .subpixel import refine_disparity
from .texture import TextureSource, check_depth_scale, make_patch, source_text, texture_source
from .transform import RoadDisparityModel, fit_road_disparity, sgbm_disparity, transform_disparity

__all__ = ["StereoDefects", "StereoResult", "DefectInstance", "FrameFusion", "FusionOptions", "PairEvidence",
           "SegmentParams",
           "RoadDisparityModel",
           "f1_score", "fit_road_disparity", "load_disparity", "load_label", "reconstruct_instance",
           "refine_disparity", "segment_defects", "sgbm_disparity", "transform_disparity"]


class StereoDefects:
    name = "stereo_defects"
    description = "stereo pair or disparity map -> pothole defect models (Fan et al. disparity transformation)"
    produces = "defects"
    Params = StereoDefectsParams

    def _residual(self, inputs: dict[str, Any], p: StereoDefectsParams) -> SimpleNamespace:
        """The inputs checked, the disparity (matched from a pair when given one), the road model
        and the residual to it in noise units (segment.road_residual): what detection and fusion start from."""
        transformed_in = bool(inputs.get("transformed", False))
        K = camera_matrix(inputs["K"], "calibration K") if inputs.get("K") is not None else None
        baseline = inputs.get("baseline")
        if baseline is not None and not (np.isfinite(baseline) and baseline > 0):
            raise RoadtwinError(f"{self.name}: baseline must be a positive number of meters, got {baseline!r}")
        try:
            depth_scale = check_depth_scale(inputs.get("depth_scale"))
        except ValueError as exc:
            raise RoadtwinError(f"{self.name}: {exc}") from None
        missing = " and ".join(n for n, v in (("K", K), ("baseline", baseline)) if v is None)
        if inputs.get("disparity") is not None:
            src = inputs["disparity"]
            src_name = "disparity array" if isinstance(src, np.ndarray) else str(src)
            if not transformed_in and missing:
                raise RoadtwinError(f"{src_name}: 3D defect models need the calibration ({missing} missing; "
                                    "or transformed=True for defect pixels only)")
            if isinstance(src, np.ndarray):
                disp = np.asarray(src, np.float64).copy()
                disp[~np.isfinite(disp) | (disp <= 0)] = np.nan
                source = "array"
            else:
                disp = read_disparity(Path(src), p.disparity_scale, transformed_in)
                source = str(src)
        elif inputs.get("left") is not None and inputs.get("right") is not None:
            lname = "left image (array)" if isinstance(inputs["left"], np.ndarray) else str(inputs["left"])
            rname = "right image (array)" if isinstance(inputs["right"], np.ndarray) else str(inputs["right"])
            if missing:
                raise RoadtwinError(f"{lname}: a stereo pair needs the calibration K and baseline ({missing} missing)")
            left, source = read_image(inputs["left"], "left")
            right, _ = read_image(inputs["right"], "right")
            if left.shape[:2] != right.shape[:2]:
                raise RoadtwinError(f"{rname}: left and right images differ in size: right {right.shape[1]}x"
                                    f"{right.shape[0]} px, left {lname} {left.shape[1]}x{left.shape[0]} px")
            disp = sgbm_disparity(left, right, p.max_disparity)
            if p.subpixel_sigma_u_px > 0:
                reject = (p.subpixel_reject_error or np.inf, p.subpixel_reject_residual or np.inf)
                disp = refine_disparity(left, right, disp, (p.subpixel_sigma_u_px, p.subpixel_sigma_v_px),
                                        reject=None if np.isinf(reject).all() else reject)
        else:
            raise RoadtwinError(f"{self.name}: give a disparity map or a rectified left + right pair")
        source = str(inputs.get("source") or source)
        if inputs.get("road_mask") is not None:
            disp = apply_road_mask(disp, inputs["road_mask"], source)
        valid = np.isfinite(disp)
        if valid.mean() < 0.05:
            raise RoadtwinError(f"{source}: only {100 * valid.mean():.1f} % of pixels have a disparity; no road to model")
        seg = SegmentParams(k_grow=p.k_grow, k_seed=p.k_seed, k_region=p.k_region, min_area_frac=p.min_area_frac,
                            min_depth_m=p.floor_depth_m, min_area_m2=p.floor_area_m2,
                            border_px=p.border_px, refit_k=0.0 if transformed_in else p.road_refit_k)
        road = None
        if transformed_in:
            dt = disp
        else:
            try:
                dt, road = transform_disparity(disp)
            except ValueError as exc:
                raise RoadtwinError(f"{source}: {exc}") from None
        z, valid_z, sigma = road_residual(dt, seg, with_sigma=True)
        return SimpleNamespace(transformed=transformed_in, disp=disp, K=K, baseline=baseline, source=source, seg=seg,
                               dt=dt, road=road, depth_scale=depth_scale, z=z, valid=valid_z, sigma=sigma)

    def run(self, inputs: dict[str, Any], params: StereoDefectsParams | None = None,
            fusion: FrameFusion | None = None) -> StereoResult:
        """One frame's defects. ``fusion`` (metric inputs with ``inputs["cam_to_world"]``): other
        pairs' evidence of the drive is fused with this one's before detecting (fusion.py);
        :meth:`run_sequence` gathers it for a whole drive."""
        p = check_params(params or StereoDefectsParams(), self.name)
        r = self._residual(inputs, p)
        ev = self._evidence(inputs, r, p) if fusion is not None and not r.transformed else None
        return self._detect(inputs, p, r, fusion, ev)

    def _detect(self, inputs: dict[str, Any], p: StereoDefectsParams, r: SimpleNamespace,
                fusion: FrameFusion | None = None, ev: PairEvidence | None = None,
                fusion_options: FusionOptions | None = None) -> StereoResult:
        """Detection and meshing on a residual (:meth:`_residual`), fused with ``fusion``'s pairs
        onto this pair's evidence ``ev`` when given."""
        transformed_in, disp, K, baseline, source, seg = r.transformed, r.disp, r.K, r.baseline, r.source, r.seg
        dt, road, depth_scale, z, valid_z, sigma = r.dt, r.road, r.depth_scale, r.z, r.valid, r.sigma
        if fusion is not None and not transformed_in:
            z, valid_z, sigma, _ = fused_residual(fusion, ev, r.z, r.valid, r.sigma, r.seg, fusion_options)
        metric = None
        if not transformed_in and (p.floor_depth_m > 0 or p.floor_area_m2 > 0):  # units: px of a raw disparity
            metric = metric_road_depth(z * sigma, disp, valid_z & (z > -p.k_grow), K, float(baseline))
        labels = segment_residual(z, valid_z, seg, metric)
        models: list[DefectModel] = []
        instances: list[DefectInstance] = []
        if not transformed_in:
            stem = safe_prim_name(Path(source).stem if source != "array" else "stereo", empty="frame", lead="f")
            for i in range(1, int(labels.max()) + 1):
                try:
                    inst = reconstruct_instance(labels == i, disp, K, float(baseline), grid_m=p.grid_m)
                    m = DefectModel(f"{stem}_defect_{i:02d}", "pothole", inst.vertices, inst.faces, inst.boundary,
                                    source=source, params={"reconstructor": self.name, "instance": i,
                                                           "pixels": inst.pixels, "grid_m": p.grid_m,
                                                           "roll_rad": None if road is None else road.theta,
                                                           **({"depth_scale": depth_scale} if depth_scale else {})})
                except (ValueError, RoadtwinError):
                    continue  # an instance too small or too close to the image edge to mesh
                if m.depth_m < p.min_depth_m:
                    continue
                models.append(m)
                instances.append(inst)
        return StereoResult(models, labels, dt, road, instances, self._texture(inputs, K, disp.shape, p, models))

    def run_sequence(self, frames, params: StereoDefectsParams | None = None, fuse_frames: int = 1,
                     lookahead: int = 0, fusion_options: FusionOptions | None = None):
        """Per pair of a drive, in order (each as :meth:`run`'s inputs plus ``cam_to_world``, the
        left camera's 4 x 4 pose, OpenCV axes), its result, detected on the evidence of
        ``fuse_frames`` pairs fused on it: the pair, the ``lookahead`` pairs after it and the rest
        before it (fusion.py). 1 (default) = each pair alone, as :meth:`run`. Why: one pair's
        matcher noise hides shallow far potholes that several pairs see; the later pairs see
        them nearer (a pair's result then comes ``lookahead`` pairs late). ``fusion_options``:
        fusion.FusionOptions (default: none; docs/stereo_detector.md, "Multi-pair fusion")."""
        if not (isinstance(fuse_frames, (int, np.integer)) and fuse_frames >= 1):
            raise RoadtwinError(f"{self.name}: fuse_frames must be an integer >= 1, got {fuse_frames!r}")
        if not (isinstance(lookahead, (int, np.integer)) and 0 <= lookahead < fuse_frames):
            raise RoadtwinError(f"{self.name}: lookahead must be an integer in [0, fuse_frames), got {lookahead!r}")
        if fuse_frames == 1:
            yield from (self.run(inputs, params) for inputs in frames)
            return
        p = check_params(params or StereoDefectsParams(), self.name)

        refit = bool(fusion_options and fusion_options.refit_road)

        def prepare(inputs):           # each pair matched once: its residual serves its evidence and its detection
            r = self._metric_residual(inputs, p)
            return (inputs, r), self._evidence(inputs, r, p, plane_depth=refit)

        def detect(state, ev, others):
            inputs, r = state
            return self._detect(inputs, p, r, FrameFusion(others), ev, fusion_options)

        yield from fused_sequence(frames, prepare, detect, int(fuse_frames), int(lookahead))

    def evidence(self, inputs: dict[str, Any], params: StereoDefectsParams | None = None) -> PairEvidence | None:
        """One pair's evidence for fusion (fusion.py step 1; None without road): its depth below
        the local road model, with ``inputs["cam_to_world"]``."""
        p = check_params(params or StereoDefectsParams(), self.name)
        return self._evidence(inputs, self._metric_residual(inputs, p), p)

    def _metric_residual(self, inputs: dict[str, Any], p: StereoDefectsParams) -> SimpleNamespace:
        r = self._residual(inputs, p)
        if r.transformed:
            raise RoadtwinError(f"{r.source}: fusing pairs needs metric disparity (K, baseline), not a transformed map")
        return r

    def _evidence(self, inputs: dict[str, Any], r: SimpleNamespace, p: StereoDefectsParams,
                  plane_depth: bool = True) -> PairEvidence | None:
        return pair_evidence(r.z, r.valid, r.sigma, r.disp, r.K, float(r.baseline), pose_of(inputs, self.name), p.k_grow,
                             plane_depth=plane_depth)

    def reconstruct(self, inputs: dict[str, Any], params: StereoDefectsParams | None = None) -> list[DefectModel]:
        """The models, untextured: a look needs texture files, which :meth:`write` makes."""
        return self.run(inputs, params).models

    def _texture(self, inputs: dict[str, Any], K: np.ndarray | None, shape: tuple[int, int],
                 p: StereoDefectsParams, models: list[DefectModel]) -> TextureSource | None:
        """The frame's texture source when the assets are to be textured (``p.texture``, metric
        models and a colour image: ``inputs["rgb"]``, else a pair's ``left``)."""
        if not (p.texture and models):
            return None
        try:
            return texture_source(inputs, K, shape, texel_m=p.texel_m, road_albedo=p.road_albedo)
        except ValueError as exc:
            raise RoadtwinError(str(exc)) from None

    def write(self, result: StereoResult, out: str | Path) -> list[Path]:
        """Write one library asset per model plus ``mask.png`` (defect pixels 255) and
        ``instances.json`` into ``out`` (replaced atomically). With ``result.texture`` each asset
        wears its footprint's pixels (``textures/NAME_diffuse.png``, a bound UsdPreviewSurface)."""
        import cv2

        paths = []
        with atomic_output_dir(out) as tmp:
            if not cv2.imwrite(str(tmp / "mask.png"), ((result.labels > 0) * 255).astype(np.uint8)):
                raise RoadtwinError(f"{out}: cannot write mask.png")
            cv2.imwrite(str(tmp / "instances.png"), result.labels.astype(np.uint16))
            meta = {"instances": int(result.labels.max()),
                    "roll_rad": None if result.road_model is None else result.road_model.theta,
                    "models": []}
            for m, inst in zip(result.models, result.instances):
                if result.texture is not None:
                    m = _textured(m, inst, result.labels == m.params["instance"], result.texture, tmp / "textures")
                write_defect_asset(m, tmp / f"{m.name}.usda")
                paths.append(Path(out) / f"{m.name}.usda")
                meta["models"].append({"name": m.name, **{k: v for k, v in m.attributes().items()}})
            (tmp / "instances.json").write_text(json.dumps(meta, indent=2))
        return paths


def _textured(model: DefectModel, inst: DefectInstance, mask: np.ndarray, src: TextureSource,
              tex_dir: Path) -> DefectModel:
    """The model with its look (``tex_dir/NAME_diffuse.png``, st affine in local XY) and a
    source naming the frame, the instance and the license; unchanged when no texel is seen."""
    import cv2

    patch = make_patch(src, inst, mask)
    if patch is None:
        return model
    tex_dir.mkdir(exist_ok=True)
    diffuse = tex_dir / f"{model.name}_diffuse.png"
    if not cv2.imwrite(str(diffuse), cv2.cvtColor(patch.albedo, cv2.COLOR_RGBA2BGRA)):
        raise RoadtwinError(f"{diffuse}: cannot write the texture")
    look = DefectLook.fit({"diffuse": str(diffuse)}, model.vertices, patch.st)
    if look is None:
        raise RoadtwinError(f"{model.name}: the patch's st is not affine in local XY")
    params = {**model.params, "texture": {"frame": src.frame, "license": src.license, "texel_m": patch.texel_m,
                                          "footprint_area_m2": round(patch.area_m2, 6),
                                          "road_albedo": src.road_albedo}}
    return replace(model, look=look, params=params,
                   source=source_text(src, model.source, int(model.params["instance"]), int(model.params["pixels"])))


@hookimpl
def roadtwin_register_reconstructors(register):
    register(StereoDefects())
