"""Cross-validation of the mixed arm (c): its synthetic share per batch and its schedule are
chosen inside the real TRAIN frames of a fraction, never on val or test.

The fraction's real subset is split in k folds by road (road_defects_br frame names carry the
road; by frame where there are fewer roads than folds). For each grid point (ratio, schedule)
and fold, a mixed model is trained on the other folds plus the synthetic frames for a shorter
budget (--cv-steps, split between the two phases as P : R) and evaluated on the held-out fold.
Intersections and unions are summed over the folds; the point with the highest pooled IoU of
--cv-metric (pothole by default, the issue's target) wins, ties to the earlier grid point.

A synthetic set may carry pixels of real train frames (photo defect library, photo road
surfaces): bench/synthetic_set.py lists their stems in ``<synthetic>/sources.json``
(bench/_synthetic_sources.py). A fold whose held-out frames are listed there is not held out:
it is refused before any model is trained (:func:`leak_guard`, :func:`check_leak`). A set
without the file (made before provenance was recorded) is used with one line saying its
provenance is unknown; the CV record says which (``leak_checked``).

A fair photo set per fold: ``perception.py frames`` lists, per fraction, the frames of its real
subset and, per fold, that subset less the fold's held-out frames (:func:`fold_frame_lists`); a
library built from a fold's list (docs/perception/efficientnet/gpu_synthetic.sh ``PHOTOS=``) gives
that fold's set, and ``--cv-synthetic DIR0 DIR1 ...`` trains fold k's CV models with set k, each
checked against its own fold only (:func:`fold_set`).
"""
from __future__ import annotations

import itertools
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from roadtwin_core.errors import RoadtwinError

from _perception_arms import SCHEDULES, Config, train_arm
from _perception_data import CLASSES, SOURCES_FILE, Frames, cv_folds, frame_stem, real_subset, road_of
from _perception_report import iou_table
from _perception_train import evaluate, to_device


def _sources_record(folder) -> tuple[set[str], set[str]] | None:
    """(every real frame stem whose pixels entered the synthetic set, those whose labelled defects
    it wears as photo library assets), read once from its ``sources.json``; None (not recorded).
    A record made before scenes were kept counts all its frames as defect sources."""
    path = Path(folder) / SOURCES_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
        every = {frame_stem(f) for f in record["frames"]}
        if "scenes" not in record:
            return every, every
        return every, {frame_stem(f) for scene in record["scenes"].values() for f in scene["defect_assets"].values() if f}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise RoadtwinError(f"{path}: not a provenance record of bench/synthetic_set.py ({exc.__class__.__name__})") from None


def synthetic_sources(folder) -> set[str] | None:
    """Stems of the real frames whose pixels entered the synthetic set, or None (not recorded)."""
    record = _sources_record(folder)
    return None if record is None else record[0]


def check_leak(folder, sources: set[str] | None, held: list[str], where: str) -> bool:
    """Raise when held-out real frames are among the synthetic set's sources; True if checked."""
    if sources is None:
        return False
    leaked = sorted(s for s in held if frame_stem(s) in sources)
    if leaked:
        roads = sorted({road_of(frame_stem(s)) for s in leaked})
        raise RoadtwinError(
            f"{Path(folder) / SOURCES_FILE}: {len(leaked)} of the {len(held)} train frames held out in {where} "
            f"({len(roads)} road(s): {', '.join(roads[:4])}{' ...' if len(roads) > 4 else ''}) are textures of this "
            f"synthetic set (e.g. {frame_stem(leaked[0])}), so CV would score it on its own sources; rebuild the photo "
            f"library (roadtwin reconstruct photos) and road textures without the held-out roads (one set per fold), "
            f"or give --mix RATIO:SCHEDULE")
    return True


def check_selection_sources(synthetic, select_dir, stems: list[str]) -> dict | None:
    """Refuse a selection folder whose frames lent their labelled defects to the synthetic set:
    a choice made there would reward recognising its own pothole and crack pixels (the photo
    set's +7 train pothole, docs/perception/efficientnet/photo_vs_parametric). Frames that gave
    only label-free road texture are counted, not refused. None when there is nothing to check."""
    if synthetic is None:
        return None
    record = _sources_record(synthetic)
    if record is None:
        return {"sources_known": False}
    every, defects = record
    held = [frame_stem(s) for s in stems]
    leaked = sorted(s for s in held if s in defects)
    if leaked:
        roads = sorted({road_of(s) for s in leaked})
        raise RoadtwinError(
            f"--select {select_dir}: {len(leaked)} of its {len(held)} frames ({', '.join(roads[:4])}"
            f"{' ...' if len(roads) > 4 else ''}; e.g. {leaked[0]}) lent their labelled defects to "
            f"{Path(synthetic) / SOURCES_FILE}, so the selection would score the set on its own sources; select on "
            f"frames the photo library was not built from")
    return {"sources_known": True, "road_texture_frames": sum(s in every for s in held)}


def labels_beyond_fraction(real: Frames, subset: Frames, sources: set[str] | None) -> list[str] | None:
    """Train frames outside a fraction's real subset that the synthetic set was made from (their
    labels cut its photo defects and defect-free road textures): labels the fraction's arms are not
    given, used through the twin. None when the set's provenance is unknown."""
    if sources is None:
        return None
    inside = {frame_stem(s) for s in subset.stems}
    return sorted(frame_stem(s) for s in real.stems if frame_stem(s) in sources and frame_stem(s) not in inside)


def fold_set(synth: Frames | list[Frames], fold: int) -> Frames:
    """The synthetic set fold ``fold``'s CV models train with: one for all folds, or the fold's own
    (``--cv-synthetic``, in fold order)."""
    return synth[fold] if isinstance(synth, (list, tuple)) else synth


def _where(fold: int, n_folds: int, fraction: float, synth) -> str:
    own = f" (--cv-synthetic folder {fold})" if isinstance(synth, (list, tuple)) else ""
    return f"CV fold {fold + 1} of {n_folds}{own} at {round(fraction * 100):g} %"


def leak_guard(fractions, real: Frames, synth: Frames | list[Frames], cfg: Config, k: int, log=print) -> bool:
    """Every fold of every fraction checked against the set it trains with, before any training;
    True if every such set's provenance is known."""
    folders = list(dict.fromkeys(s.folder for s in (synth if isinstance(synth, (list, tuple)) else [synth])))
    unknown = [f for f in folders if synthetic_sources(f) is None]
    for folder in unknown:
        log(f"{folder}: no {SOURCES_FILE}: the real frames this synthetic set was made from are unknown, so the "
            f"mixed arm's CV cannot check that its held-out train roads are not in it")
    if len(unknown) == len(folders):
        return False
    for fraction in fractions:
        sub = real_subset(real, fraction, cfg.subset_seed)
        folds, _ = cv_folds(sub.stems, k, cfg.subset_seed)
        for f, held in enumerate(folds):
            fs = fold_set(synth, f)
            check_leak(fs.folder, synthetic_sources(fs.folder), [sub.stems[i] for i in held],
                       _where(f, len(folds), fraction, synth))
    return not unknown


def pct(fraction: float) -> str:
    return f"{round(fraction * 100):g}"


def fold_frame_lists(real: Frames, fractions, k: int, seed: int) -> dict[str, list[str]]:
    """The real frames a fair photo set may draw from, sorted stems by list name: per fraction its
    real subset (``frames_PCT``: real_subset's choice), per CV fold that subset less the fold's
    held-out frames (``frames_PCT_fold{f}``, f from 0: cv_folds' choice); no fold lists for k = 0."""
    lists = {}
    for fraction in fractions:
        sub = real_subset(real, fraction, seed)
        lists[f"frames_{pct(fraction)}"] = sorted(frame_stem(s) for s in sub.stems)
        folds = cv_folds(sub.stems, k, seed)[0] if k else []
        for f, held in enumerate(folds):
            out = set(held.tolist())
            lists[f"frames_{pct(fraction)}_fold{f}"] = sorted(frame_stem(s) for i, s in enumerate(sub.stems) if i not in out)
    return lists


def grid_points(ratios, schedules) -> list[dict]:
    for s in schedules:
        if s not in SCHEDULES:
            raise RoadtwinError(f"--cv-schedules: {s!r} is not one of {', '.join(SCHEDULES)}")
    for r in ratios:
        if not 0 < r < 1:
            raise RoadtwinError(f"--cv-ratios: {r} is not in (0, 1)")
    return [{"ratio": float(r), "schedule": s} for s, r in itertools.product(schedules, ratios)]


def parse_mix(text: str) -> dict:
    """``RATIO:SCHEDULE`` (e.g. 0.25:finetune) -> a grid point, given by hand instead of CV."""
    try:
        ratio, schedule = text.split(":")
        return grid_points([float(ratio)], [schedule])[0]
    except ValueError:
        raise RoadtwinError(f"--mix: {text!r} is not RATIO:SCHEDULE (e.g. 0.25:constant)") from None


def cv_config(cfg: Config, cv_steps: int) -> Config:
    total = cfg.pretrain_steps + cfg.steps
    p = int(round(cv_steps * cfg.pretrain_steps / total)) if total else 0
    return replace(cfg, pretrain_steps=p, steps=cv_steps - p)


def cv_point(fraction: float, point: dict, k: int, real: Frames, synth: Frames, cfg: Config, cv_steps: int,
             seed: int, device) -> dict:
    """One grid point: its k fold models, intersections and unions summed over the folds."""
    parts = [cv_one(fraction, point, f, k, real, synth, cfg, cv_steps, seed, device, lambda *a: None) for f in range(k)]
    done = [p for p in parts if p["steps"]]
    checked = bool(done) and all(p.get("leak_checked", False) for p in done)
    return {**parts[0], "leak_checked": checked, "fold": "all", "held_out": [p["held_out"] for p in done],
            "synthetic_by_fold": [p["synthetic"] for p in done],
            "synthetic_from_train_beyond_folds": [p["synthetic_from_train_beyond_fold"] for p in done],
            "steps": sum(p["steps"] for p in done), "seconds": round(sum(p["seconds"] for p in done), 2),
            "I": np.sum([p["I"] for p in parts], 0).tolist(), "U": np.sum([p["U"] for p in parts], 0).tolist(),
            "steps_per_model": max(p["steps"] for p in parts)}


def cv_one(fraction: float, point: dict, fold: int, k: int, real: Frames, synth: Frames, cfg: Config,
           cv_steps: int, seed: int, device, log=print) -> dict:
    """One (grid point, fold) model: trained on the other folds, scored on this one."""
    sub = real_subset(real, fraction, cfg.subset_seed)
    folds, by = cv_folds(sub.stems, k, cfg.subset_seed)
    if fold >= len(folds):             # fewer frames than folds: this fold does not exist
        return {"fraction": fraction, "point": point, "fold": fold, "folds": len(folds), "by": by, "held_out": [],
                "steps": 0, "seconds": 0.0, "I": [0] * len(CLASSES), "U": [0] * len(CLASSES)}
    held, fs = folds[fold], fold_set(synth, fold)
    sources = synthetic_sources(fs.folder)
    checked = check_leak(fs.folder, sources, [sub.stems[i] for i in held], _where(fold, len(folds), fraction, synth))
    rest = np.setdiff1d(np.arange(len(sub.stems)), held)
    beyond = labels_beyond_fraction(real, sub.subset(rest), sources)      # train frames outside its training folds
    model, infos = train_arm("mixed", cv_config(cfg, cv_steps), seed, sub.subset(rest), fs, device, point,
                             log=log, style=sub.subset(rest))
    i, u, _ = evaluate(model, to_device(sub.subset(held), device), device, cfg.batch)
    return {"fraction": fraction, "point": point, "fold": fold, "folds": k, "by": by,
            "held_out": sorted({road_of(s) for s in sub.subset(held).stems}) if by == "road" else f"{len(held)} frames",
            "steps": sum(p["steps"] for p in infos), "seconds": round(sum(p["seconds"] for p in infos), 2),
            "I": i.sum(0).tolist(), "U": u.sum(0).tolist(), "leak_checked": checked, "synthetic": fs.folder,
            "synthetic_from_train_beyond_fold": None if beyond is None else len(beyond)}


def choose(fraction: float, parts: list[dict], metric: str) -> dict:
    """The grid point with the best pooled ``metric`` over its folds; the record of the choice."""
    points: dict[str, dict] = {}
    for p in parts:
        key = f"{p['point']['ratio']:g}:{p['point']['schedule']}"
        d = points.setdefault(key, {"point": p["point"], "I": 0, "U": 0, "folds": []})
        d["I"] = np.add(d["I"], p["I"])
        d["U"] = np.add(d["U"], p["U"])
        d["folds"] += p["held_out"] if p.get("fold") == "all" else ([p["held_out"]] if p["steps"] else [])
    scores = {}
    for key, d in points.items():
        t = iou_table(np.asarray(d["I"])[None], np.asarray(d["U"])[None])
        if metric not in t:
            raise RoadtwinError(f"--cv-metric: {metric!r} is not one of {', '.join(t)}")
        scores[key] = {"point": d["point"], metric: t[metric], "table": t, "folds": d["folds"]}
    best = max(scores, key=lambda k: (np.nan_to_num(scores[k][metric], nan=-1.0), -list(scores).index(k)))
    return {"fraction": fraction, "metric": metric, "chosen": scores[best]["point"], "scores": scores,
            "steps_per_model": max(p.get("steps_per_model", p["steps"]) for p in parts), "folds": parts[0]["folds"], "by": parts[0]["by"],
            "leak_checked": all(p.get("leak_checked", False) for p in parts),
            "synthetic_from_train_beyond_folds": parts[0].get("synthetic_from_train_beyond_folds"),
            "chosen_on": "k-fold cross-validation over the real train frames of this fraction (never val/test)"}


def cv_path(cache: Path, fraction: float) -> Path:
    return Path(cache) / f"cv_{round(fraction * 100):g}.json"


def set_names(synthetic, cv_synthetic=None) -> dict:
    """What a CV record names: the set the arm's final run uses (choose-set compares those) and,
    with ``--cv-synthetic``, the per-fold sets its CV models trained with."""
    return {"synthetic": str(synthetic), **({"cv_synthetic": [str(Path(d)) for d in cv_synthetic]} if cv_synthetic else {})}


def cross_validate(fraction: float, real: Frames, synth: Frames | list[Frames], cfg: Config, points: list[dict], k: int,
                   cv_steps: int, metric: str, seed: int, device, cache: Path | None, log=print, final=None) -> dict:
    """The mixed arm's choice for a fraction: read from ``cache`` if made, else computed there.
    ``synth``: one set for every fold, or one per fold; ``final``: the set of the arm's run."""
    path = cv_path(cache, fraction) if cache else None
    per_fold = isinstance(synth, (list, tuple))
    if path is not None and path.exists():
        record = json.loads(path.read_text())
        made_with = record.get("cv_synthetic")
        if made_with != ([s.folder for s in synth] if per_fold else None):
            was = "per-fold sets " + ", ".join(made_with) if made_with else "one set"
            raise RoadtwinError(f"{path}: a CV choice made with {was}, not this call's "
                                f"{'--cv-synthetic' if per_fold else 'single set'}: give a fresh --out")
        return record
    parts = [cv_point(fraction, p, k, real, synth, cfg, cv_steps, seed, device) for p in points]
    names = set_names(final or (None if per_fold else synth.folder), [s.folder for s in synth] if per_fold else None)
    record = {**choose(fraction, parts, metric), **names}
    if path is not None:
        write_json(path, record)
    log(f"  mixed arm at {round(fraction * 100):g} %: chose ratio {record['chosen']['ratio']:g}, {record['chosen']['schedule']} "
        f"({metric} by {k}-fold CV on train {record['by']}s)")
    return record


def choose_set(records: list[dict], metric: str | None = None) -> dict:
    """Which synthetic set the mixed arm uses: the one whose own CV choice scores best on the
    held-out train roads (records of ``cross_validate``, one per set, same fraction and folds)."""
    if not records:
        raise RoadtwinError("choose-set: no CV records given")
    for key in ("fraction", "folds", "by", "steps_per_model"):
        if len({json.dumps(r.get(key)) for r in records}) > 1:
            raise RoadtwinError(f"choose-set: the CV records differ in {key} "
                                f"({', '.join(str(r.get(key)) for r in records)}): not comparable")
    metric = metric or records[0]["metric"]
    scores = {}
    for r in records:
        if "synthetic" not in r:
            raise RoadtwinError("choose-set: a CV record without its synthetic folder (made before choose-set existed)")
        best = r["scores"][f"{r['chosen']['ratio']:g}:{r['chosen']['schedule']}"]
        if metric not in best["table"]:
            raise RoadtwinError(f"--metric: {metric!r} is not one of {', '.join(best['table'])}")
        scores[r["synthetic"]] = {"point": r["chosen"], metric: best["table"][metric], "table": best["table"],
                                  "leak_checked": bool(r.get("leak_checked", False))}
    chosen = max(scores, key=lambda k: (np.nan_to_num(scores[k][metric], nan=-1.0), -list(scores).index(k)))
    return {"chosen": chosen, "point": scores[chosen]["point"], "metric": metric, "scores": scores,
            "fraction": records[0]["fraction"], "folds": records[0]["folds"], "by": records[0]["by"],
            "leak_checked": all(v["leak_checked"] for v in scores.values()),
            "chosen_on": "pooled held-out IoU of k-fold CV over the real train frames (never val/test)"}


def write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=_plain))
    tmp.replace(path)


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(type(v).__name__)
