"""The composer: layout + defect library + rules -> a town stage (docs/architecture.md#data-flow)."""
from __future__ import annotations

import contextlib
import dataclasses
import json
import shutil
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from ...atomic import atomic_output_dir, scratch_dir
from ...contracts import configured
from ...errors import RoadtwinError
from ...executors import SerialExecutor, make_executor
from ...looks.catalog import DEFAULT_DEFECT_MATERIAL, all_materials
from ...looks.prefetch import TexturePrefetch, TexturesNow
from ...looks.road_textures import RoadLooks, resolve_road_looks
from ...model import ComposeRules, DefectModel, Placement, TownLayout
from ...params import apply_params, make_params
from ...plugins import PluginManager, get_plugin_manager
from ...remesh import coarsen_defect
from ...surface import parse_surface
from ...town.markings import build_markings
from ...town.props import DEFAULT_RULES as DEFAULT_PROP_RULES, PropRule, Props, load_prop_rules, place_props
from ...town.param_priors import FieldPrior, apply_priors, load_priors
from ...town.placement import ALONG_TRAVEL, lane_length_km, place_defects
from ...usd.layout_io import read_layout
from ...usd.library import ASSET_SUFFIXES, DEFECT_CLASS, library_asset_files, read_defect_asset, write_defect_asset
from ...usd.town import TownParts, write_town
from ...usd.validate import validate_stage
from .library_cache import library_cache_root, load_model, model_key, store_model
from .preview import write_preview
from .preview_job import PREVIEW_RENDERER, render_preview, warm_up_renderer
from .preview_scene import PreviewTown
from .sidecar import Sidecar

Progress = Callable[[str, int, int], None]


@dataclass
class ComposeResult:
    outdir: Path
    town: Path
    summary: dict


def build_library(rules: ComposeRules, pm: PluginManager, runner=None,
                  priors: dict[str, dict[str, FieldPrior]] | None = None,
                  cache: Path | None = None) -> dict[str, list[DefectModel]]:
    """``models_per_type`` seeded models per weighted type (the paper draws 1,000 instances from
    53 models); each model's randomness depends only on (seed, type, index). ``priors``
    (``--defect-priors``, :mod:`~roadtwin_core.town.param_priors`) redraw the parameters they name. Each is coarsened to
    the road mesh's edge length (:func:`~roadtwin_core.remesh.coarsen_defect`), the costly part:
    ``runner`` (a local executor) spreads the models over its cores. ``cache``: a folder of
    models made before by the same code (:mod:`.library_cache`); only the missing ones are made."""
    priors = priors or {}
    items = [(t, k) for t in sorted(rules.type_weights) if rules.type_weights[t] > 0 for k in range(rules.models_per_type)]
    keys = [model_key(pm.get("defect_types", t), t, k, rules.seed, rules.road_edge_m, priors.get(t)) if cache else None
            for t, k in items]
    models = [load_model(cache, key) if key else None for key in keys]
    missing = [i for i, m in enumerate(models) if m is None]
    made = (runner or SerialExecutor()).map(_library_model, (pm, rules, priors), [items[i] for i in missing])
    for i, model in zip(missing, made):
        models[i] = model
        if keys[i]:
            store_model(cache, keys[i], model)
    library: dict[str, list[DefectModel]] = {}
    for (t, _), model in zip(items, models):
        library.setdefault(t, []).append(model)
    return library


def _library_model(context, item) -> DefectModel:
    pm, rules, priors = context
    t, k = item
    dtype = pm.get("defect_types", t)
    rng = np.random.default_rng([rules.seed, sum(map(ord, t)), k])
    params = dtype.sample_params(rng)
    if priors.get(t):   # their own generator: the type's other draws stay as without priors
        params = apply_priors(params, priors[t], np.random.default_rng([rules.seed, sum(map(ord, t)), k, 1]),
                              f"defect type {t}")
    # level of detail tied to the road mesh: ~3x fewer triangles, volume within 0.5 %
    return coarsen_defect(dtype.generate(params, rng, f"{t}_{k:02d}"), rules.road_edge_m)


def add_library_folder(library: dict[str, list[DefectModel]], rules: ComposeRules, folder: Path) -> ComposeRules:
    """Mix the defect assets of a library folder (reconstructed or hand-made models) into the
    parametric ones: each joins its type's pool; a type the rules do not weight gets weight 1.
    Which files are assets is :func:`~roadtwin_core.usd.library.is_asset_file`'s rule, the one
    ``roadtwin library list/add`` use."""
    if not folder.is_dir():
        raise RoadtwinError(f"{folder}: defect library folder not found")
    files = library_asset_files(folder)
    if not files:
        suffixes = ", ".join(f"*{s}" for s in ASSET_SUFFIXES)
        raise RoadtwinError(f"{folder}: no defect assets ({suffixes}) in the library folder")
    weights = dict(rules.type_weights)
    for f in files:
        model = read_defect_asset(f)
        model.name = f"lib_{model.name}"
        library.setdefault(model.defect_type, []).append(model)
        weights.setdefault(model.defect_type, 1.0)
    return rules.replace(type_weights=weights)


class TypeTraits(NamedTuple):
    """What a defect type says of itself (contracts.DefectType's optional attributes)."""
    semantic_class: str     # default road_defect; a look-alike says road_lookalike
    along_travel: bool      # yawed with the lane (ruts)
    material: str           # the catalog material its surface wears (default worn asphalt)


def type_semantics(pm: PluginManager, types) -> dict[str, TypeTraits]:
    """Per defect type, its :class:`TypeTraits`. A type only a library folder brings (no
    registered generator) gets the defaults; a material the catalog does not author is refused."""
    registered = pm.registry("defect_types")
    known = set(all_materials())
    out = {}
    for t in sorted(types):
        dtype = registered.get(t)
        material = str(getattr(dtype, "material", DEFAULT_DEFECT_MATERIAL))
        if material not in known:
            raise RoadtwinError(f"defect type {t!r}: material {material!r} is not one the looks catalog authors "
                                f"(roadtwin_core.looks.all_materials())")
        out[t] = TypeTraits(str(getattr(dtype, "semantic_class", DEFECT_CLASS)),
                            bool(getattr(dtype, "along_travel", False)), material)
    return out


def fixed_placements(layout: TownLayout, pm: PluginManager) -> list[Placement]:
    """The layout's pinned defects, each generated from its own type, params and seed."""
    out = []
    for fd in layout.fixed:
        dtype = pm.get("defect_types", fd.defect_type)
        owner = f"{layout.source}: placement {fd.name}"
        params = make_params(dtype.Params, fd.params, owner)
        model = dtype.generate(params, np.random.default_rng(fd.seed), f"fixed_{fd.name}")
        out.append(Placement(fd.name, model, fd.x, fd.y, fd.yaw, tuple(fd.scale)))
    return out


def compose(layout_path: str | Path, outdir: str | Path, *, defects: int | None = None, seed: int | None = None,
            merger: str | None = None, surface: str | None = None, progress: Progress | None = None,
            pm: PluginManager | None = None, preview: bool = True, executor: str = "local",
            ray_address: str | None = None, workers: int | None = None,
            library_dir: str | Path | None = None, merger_params: dict[str, Any] | None = None,
            texture_writer: Callable[[Path, int], dict] | None = None,
            props: str | Path | None = "default", road_textures: str | Path | None = None,
            road_material: str | None = None, defect_priors: str | Path | None = None) -> ComposeResult:
    """``defect_priors``: ``builtin:NAME`` or a TOML file of per-type parameter distributions
    (:mod:`~roadtwin_core.town.param_priors`; ``builtin:road_defects_br`` is measured from that
    dataset's train labels). ``merger_params``: values for the merger's ``Params`` (``--param``), checked like a layout's.
    ``props``: the roadside world (``layers/props.usda``): ``"default"`` (the built-in rules),
    ``"none"`` (no props layer) or a TOML rules file (:func:`resolve_prop_rules`).
    ``road_textures``: a folder of road materials (``roadtwin reconstruct photo-surfaces``), each
    offered as a ``roadMaterial`` variant; ``road_material``: the variant selected (default asphalt).
    ``texture_writer``: ``writer(folder, seed) -> specs`` to write the textures instead of the cached
    set, which is otherwise made (or copied from the cache) in a helper process while the town is
    placed and merged.

    The preview has a helper process of its own (:mod:`~roadtwin_core.apps.compose.preview_job`): it loads the
    renderer from the start (on a machine's first run it compiles the renderer's kernels, beside
    the textures' helper instead of after it), and draws on the second core while the stage is
    written and validated. A plugin manager ``pm`` of the caller's cannot travel to another
    process: the preview then runs here, at the end. The library's models come from the user
    cache when the same code made them before (:mod:`.library_cache`), unless ``pm`` is the
    caller's (its types may be made at run time)."""
    t0 = time.perf_counter()
    prop_rules = resolve_prop_rules(props)   # a bad rules file: one line before any work
    road_looks = resolve_road_looks(road_textures, road_material)
    priors = load_priors(defect_priors) if defect_priors is not None else ({}, None)
    preview_here = pm is not None
    with contextlib.ExitStack() as stack:
        # Started first: the helpers' interpreters boot while the layout is read.
        texture_side = stack.enter_context(Sidecar()) if not texture_writer else None
        preview_side = stack.enter_context(Sidecar()) if preview and not preview_here else None
        pm = pm or get_plugin_manager()
        unknown = sorted(set(priors[0]) - set(pm.registry("defect_types")))
        if unknown:
            raise RoadtwinError(f"{defect_priors}: defect priors for unknown defect types: {', '.join(unknown)}")
        previewer = _HereOrThere(preview_side, pm) if preview else None
        layout_path = Path(layout_path)
        layout = read_layout(layout_path)
        rules = layout.rules.replace(defect_count=defects, seed=seed, merger=merger, surface=surface,
                                     library=str(library_dir) if library_dir else None).check(
            f"{layout_path}")
        if defects is None and rules.density_per_km > 0:
            rules = rules.replace(defect_count=int(round(rules.density_per_km * lane_length_km(layout.segments, rules.kinds))))
        layout.rules = rules
        merger_impl = pm.get("mergers", rules.merger)
        if merger_params:  # --param: a configured copy, the registered merger stays as it was
            merger_impl = configured(merger_impl, apply_params(merger_impl.params, merger_params, f"merger {rules.merger}"))
        report = progress or (lambda *_: None)
        textures = stack.enter_context(TexturesNow(texture_writer, rules.seed) if texture_writer
                                       else TexturePrefetch(rules.seed, texture_side, scratch_dir(outdir, "textures")))
        result = _compose(layout_path, outdir, layout, rules, pm, merger_impl, report, textures, previewer, t0,
                          executor=executor, ray_address=ray_address, workers=workers, library_dir=library_dir,
                          prop_rules=prop_rules, road_looks=road_looks, priors=priors,
                          library_cache=None if preview_here else library_cache_root())
        for side in (texture_side, preview_side):    # what they printed, now that the run succeeded
            if side is not None:
                side.replay_output()
        return result


class _HereOrThere:
    """The preview: in its helper process when there is one (loading the renderer at once,
    drawing as soon as the looks layer is written), else here, once the stage is validated."""

    def __init__(self, side: Sidecar | None, pm: PluginManager) -> None:
        self.side = side
        self.warm = None
        if side is not None:
            # the helper loads only the plugin that provides the renderer, if one does
            provider = pm.provider("renderers", PREVIEW_RENDERER)
            self.warm = side.submit(warm_up_renderer, (provider,) if provider else None)
        self.job = None

    def start(self, path: Path, town_stage: Path, title: str, town) -> None:
        if self.side is not None:
            self.job = self.side.submit(render_preview, path, town_stage, title, town)
        else:
            self.job = (path, town_stage, title, town)

    def finish(self, pm: PluginManager) -> dict:
        """Timings: ``preview_s`` (the preview's own time), ``preview_wait_s`` (what the composer
        waited for it after validating)."""
        t0 = time.perf_counter()
        if self.side is not None:
            self.side.result(self.warm)
            took = self.side.result(self.job)["preview_s"]
        else:
            path, town_stage, title, town = self.job
            write_preview(path, town_stage, pm=pm, title=title, town=town)
            took = time.perf_counter() - t0
        return {"preview_s": took, "preview_wait_s": time.perf_counter() - t0}


def _compose(layout_path: Path, outdir, layout: TownLayout, rules: ComposeRules, pm: PluginManager, merger_impl,
             report, textures: TexturePrefetch | TexturesNow, previewer: _HereOrThere | None, t0: float, *,
             executor: str, ray_address, workers, library_dir,
             prop_rules: tuple[PropRule, ...] = (), road_looks: RoadLooks = RoadLooks(),
             priors: tuple[dict, str | None] = ({}, None), library_cache: Path | None = None) -> ComposeResult:
    runner = make_executor(executor, ray_address, workers)
    # Library and markings on the local cores only: a Ray map starts and stops a cluster, costing
    # more than they do.
    local = runner if runner.name == "local" else None
    library = build_library(rules, pm, local, priors[0], library_cache) if rules.defect_count else {}
    if rules.library and rules.defect_count:
        folder = Path(library_dir) if library_dir else (layout_path.parent / rules.library)
        rules = add_library_folder(library, rules, folder)
        layout.rules = rules
    fixed = fixed_placements(layout, pm)
    rng = np.random.default_rng(rules.seed)
    kinds = type_semantics(pm, set(library) | {p.model.defect_type for p in fixed})
    placements = place_defects(layout.segments, library, rules, rng, str(layout_path), fixed,
                               along_travel=ALONG_TRAVEL | {t for t, k in kinds.items() if k.along_travel})
    semantic = {t: k.semantic_class for t, k in kinds.items()}
    defect_materials = {t: k.material for t, k in kinds.items()}
    t_place = time.perf_counter()

    bounds = _bounds(layout, pad=2.0)
    surf = parse_surface(rules.surface, bounds, rules.seed, layout.terrain)
    # Before the merge: a rule that fits nothing fails fast, with nothing written.
    t_props = time.perf_counter()
    props = place_town_props(layout, prop_rules, surf, bounds, rules.seed, str(layout_path), placements)
    props_s = time.perf_counter() - t_props
    by_segment: dict[str, list[int]] = {}
    for i, p in enumerate(placements):
        for sid in p.segment_ids:
            by_segment.setdefault(sid, []).append(i)
    owners = [by_segment.get(seg.id, []) for seg in layout.segments]
    work = [(seg, [placements[i] for i in idx]) for seg, idx in zip(layout.segments, owners)]
    # Costliest first (defects dominate a segment's merge), so no core idles on one big segment
    # at the end; results go back to layout order, so the bytes do not depend on it.
    order = sorted(range(len(work)), key=lambda k: (-len(work[k][1]), -len(work[k][0].faces), k))
    done_in_order = runner.map(_merge_segment, (merger_impl, surf, rules), [work[k] for k in order],
                               lambda done, total: report("merge", done, total))
    merged = [None] * len(work)
    for k, m in zip(order, done_in_order):
        merged[k] = m
    t_merge = time.perf_counter()
    markings = build_markings(layout.markings, layout.segments, merged, placements, executor=local)
    report("markings", 1, 1)
    t_markings = time.perf_counter()

    with atomic_output_dir(outdir) as tmp, _stop_helper_on_failure(previewer):
        (tmp / "layout").mkdir()
        shutil.copyfile(layout_path, tmp / "layout" / layout_path.name)
        (tmp / "library").mkdir()
        library_files = {}
        models = [m for ms in library.values() for m in ms] + [p.model for p in fixed]
        for m in models:
            write_defect_asset(m, tmp / "library" / f"{m.name}.usda", semantic.get(m.defect_type, DEFECT_CLASS))
            library_files[m.name] = f"./library/{m.name}.usda"
        merger_values = effective_merger_params(merger_impl)
        info = {"layout": layout_path.name, "seed": rules.seed, "surface": rules.surface,
                "merger": rules.merger, "mergerParams": json.dumps(merger_values, sort_keys=True),
                "defectCount": len(placements)}
        materials = textures.collect(tmp / "textures")
        materials.update(road_looks.copy_into(tmp / "textures"))
        t_textures = time.perf_counter()

        def start_preview():
            previewer.start(tmp / "preview.png", tmp / "town.usda",
                            f"{layout.name}: {len(layout.segments)} segments, {len(placements)} defects",
                            PreviewTown(layout, merged, owners, placements, markings, tmp / "layers/looks.usda",
                                        defect_materials))

        town = write_town(tmp, TownParts(layout, f"layout/{layout_path.name}", merged, owners, placements,
                                         library_files, info, markings, materials, semantic_classes=semantic,
                                         defect_materials=defect_materials, props=props, **road_looks.town_fields()),
                          on_looks=start_preview if previewer is not None else None)
        report("write", 1, 1)
        t_written = time.perf_counter()
        findings = validate_stage(town)
        errors = [f for f in findings if f.severity == "Error"]
        if errors:
            raise RoadtwinError(f"composed stage fails validation: {errors[0].validator}: {errors[0].message}")
        t_write = time.perf_counter()
        summary = _summary(layout, placements, merged, rules, findings,
                           {"place_s": t_place - t0, "props_s": props_s, "merge_s": t_merge - t_place - props_s,
                            "markings_s": t_markings - t_merge,
                            "textures_s": t_textures - t_markings, "write_s": t_written - t_textures,
                            "validate_s": t_write - t_written})
        summary["merger_params"] = merger_values
        summary["defect_priors"] = priors[1]
        summary["markings"] = len(markings)
        summary["props"] = {"instances": props.count if props else 0, "by_rule": props.by_rule() if props else {}}
        if props and props.map_objects:    # only a layout with map objects (others: the same bytes as before)
            summary["props"]["map_objects"] = props.map_objects
        summary["materials"] = len(materials)
        if previewer is not None:
            summary["timings_s"].update({k: round(v, 3) for k, v in previewer.finish(pm).items()})
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    outdir = Path(outdir).resolve()
    return ComposeResult(outdir, outdir / "town.usda", summary)


@contextlib.contextmanager
def _stop_helper_on_failure(previewer: _HereOrThere | None):
    """A failed compose stops the helper before its staging folder is removed: no preview is
    written into a folder that is going away."""
    try:
        yield
    except BaseException:
        if previewer is not None and previewer.side is not None:
            previewer.side.close()
        raise


def effective_merger_params(merger_impl) -> dict:
    """The merger's effective parameters (defaults and ``--param`` values): the stage and the
    summary record what made the town, so a run with other values can be told apart and repeated."""
    params = getattr(merger_impl, "params", None)
    return dataclasses.asdict(params) if dataclasses.is_dataclass(params) and not isinstance(params, type) else {}


def _merge_segment(context, item):
    """One segment's merge; module-level so process pools and Ray can ship it."""
    merger_impl, surf, rules = context
    segment, placements = item
    return merger_impl.merge(segment, placements, surf, rules)


def resolve_prop_rules(props: str | Path | None) -> tuple[PropRule, ...]:
    """The props rules ``compose(props=...)`` names: ``"default"`` the built-in rules, ``"none"``
    (or None) none, anything else a TOML rules file (:func:`~roadtwin_core.town.props.load_prop_rules`:
    a missing or bad file is one line)."""
    if props is None or str(props).lower() == "none":
        return ()
    if str(props).lower() == "default":
        return DEFAULT_PROP_RULES
    return load_prop_rules(props)


def place_town_props(layout: TownLayout, prop_rules: tuple[PropRule, ...], surf, bounds, seed: int,
                     owner: str, placements: list[Placement] = ()) -> Props | None:
    """The town's props on the surface model's height (None without rules), clear of the
    ``placements`` (each defect's disc: a car stopped in a lane never covers one). Props and
    terrain reach beyond the road, where a surface grid (ISO 8608) has no samples: points outside
    its bounds take the height at the nearest border."""
    if not prop_rules:
        return None
    lo, hi = np.array(bounds[:2]), np.array(bounds[2:])

    def height(xy):
        return np.asarray(surf.height(np.clip(np.asarray(xy, np.float64), lo, hi)), np.float64)
    reach: dict[int, float] = {}      # per model: its farthest footprint point from its origin
    for p in placements:
        if id(p.model) not in reach:
            reach[id(p.model)] = float(np.hypot(*np.asarray(p.model.footprint, np.float64)[:, :2].T).max())
    taken = np.array([(p.x, p.y, reach[id(p.model)] * max(p.scale[:2])) for p in placements]).reshape(-1, 3)
    return place_props(layout.segments, prop_rules, height, seed, owner, taken=taken, map_objects=layout.objects)


def _bounds(layout: TownLayout, pad: float) -> tuple[float, float, float, float]:
    pts = np.concatenate([s.vertices[:, :2] for s in layout.segments])
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _summary(layout, placements: list[Placement], merged, rules, findings, timings) -> dict:
    kinds = Counter(s.kind for s in layout.segments)
    types = Counter(p.model.defect_type for p in placements)
    attrs = [p.attributes() for p in placements]
    return {
        "layout": layout.source, "seed": rules.seed, "surface": rules.surface, "merger": rules.merger,
        "segments": len(layout.segments), "segments_by_kind": dict(sorted(kinds.items())),
        "defects": len(placements), "defects_by_type": dict(sorted(types.items())),
        "straddling_defects": sum(1 for p in placements if len(p.segment_ids) > 1),
        "road_area_m2": float(sum(s.polygon().area for s in layout.segments)),
        "defect_area_m2": float(sum(a["areaM2"] for a in attrs)),
        "defect_volume_m3": float(sum(a["volumeM3"] for a in attrs)),
        "triangles": int(sum(len(m.faces) for m in merged)),
        "validation": {"errors": sum(f.severity == "Error" for f in findings),
                       "warnings": sum(f.severity == "Warn" for f in findings)},
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
