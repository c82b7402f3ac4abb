"""Metrics and the report of bench/perception.py: dataset IoU per class, mIoU with and without
background, paired bootstrap intervals of each arm's gain over (a) real-only at the same fraction
and seeds, a results JSON, a markdown table, gains.png and grid.jpg, from the runs' JSONs.
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from roadtwin_core.errors import RoadtwinError

from _perception_arms import Config
from _perception_data import CLASSES, road_of

REPORTED = ("pothole", "crack", "ego_lane", "background")
METRICS = REPORTED + ("mIoU", "mIoU_fg")


def iou_table(inter: np.ndarray, union: np.ndarray) -> dict:
    """Dataset IoU per class (intersections and unions summed over frames; NaN where a class is
    in neither prediction nor label), mIoU over all classes and over the foreground ones."""
    i, u = np.asarray(inter).sum(0).astype(float), np.asarray(union).sum(0).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(u > 0, i / np.where(u > 0, u, 1), np.nan)
    out = {c: float(iou[k]) for k, c in enumerate(CLASSES)}
    out["mIoU"] = float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")
    out["mIoU_fg"] = float(np.nanmean(iou[1:])) if np.isfinite(iou[1:]).any() else float("nan")
    return out


def bootstrap_gain(ia, ua, ib, ub, n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> dict:
    """Paired bootstrap over evaluation frames of the IoU gain of b over a. Inputs (F, C): per
    frame intersections and unions (summed over seeds), the same frames in both. Each replicate
    draws F frames with replacement, the same draw for both arms. Per metric: the observed gain
    and the percentile interval."""
    ia, ua, ib, ub = (np.asarray(v, dtype=np.float64) for v in (ia, ua, ib, ub))
    f = ia.shape[0]
    rng = np.random.default_rng(seed)
    w = np.stack([np.bincount(rng.integers(0, f, f), minlength=f) for _ in range(n_boot)]).astype(np.float64)

    def metrics(i, u):   # (..., C) sums -> dict of arrays
        with np.errstate(invalid="ignore", divide="ignore"):
            iou = np.where(u > 0, i / np.where(u > 0, u, 1), np.nan)
            d = {c: iou[..., k] for k, c in enumerate(CLASSES)}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                d["mIoU"] = np.nanmean(iou, -1)
                d["mIoU_fg"] = np.nanmean(iou[..., 1:], -1)
        return d

    obs_a, obs_b = metrics(ia.sum(0), ua.sum(0)), metrics(ib.sum(0), ub.sum(0))
    rep_a, rep_b = metrics(w @ ia, w @ ua), metrics(w @ ib, w @ ub)
    q = [(1 - level) / 2 * 100, (1 + level) / 2 * 100]
    out = {}
    for key in obs_a:
        diff = rep_b[key] - rep_a[key]
        lo, hi = np.nanpercentile(diff, q) if np.isfinite(diff).any() else (np.nan, np.nan)
        out[key] = {"gain": float(obs_b[key] - obs_a[key]), "lo": float(lo), "hi": float(hi)}
    return out


TWO_DOMAIN_ARMS = ("pretrain", "mixed")     # the arms --domain-bn changes; the others are the same runs without it


# Config keys added after runs were recorded, at their defaults: the behaviour those runs had (a run
# JSON written before ``bn_stats`` existed was evaluated with its trained statistics, and so on).
ADDED_KEYS = {k: getattr(Config(), k) for k in ("style", "bn_stats", "domain_bn", "pseudo_keep", "encoder_lr")}


def _comparable(run: dict) -> dict:
    """A run's configuration as far as it must match the others': ``domain_bn`` apart (it changes
    only (b) and (c), checked among them)."""
    return {k: v for k, v in {**ADDED_KEYS, **run["config"]}.items() if k != "domain_bn"}


def _as_trained(run: dict, f: Path) -> dict:
    """The run evaluated with its trained batch-norm statistics (``report --as-trained``): its
    ``as_trained`` evaluation where AdaBN replaced them, the run itself where it never did."""
    cfg = {**ADDED_KEYS, **run["config"]}
    if cfg["bn_stats"] == "train":
        return run
    if "as_trained" not in run:
        raise RoadtwinError(f"{f}: evaluated after AdaBN and without its as-trained evaluation: --as-trained cannot use it")
    return {**run, "I": run["as_trained"]["I"], "U": run["as_trained"]["U"], "config": {**cfg, "bn_stats": "train"}}


def _on_selection(run: dict, f: Path) -> dict:
    """The run as evaluated on its ``--select`` folder (``--on select``)."""
    if "select" not in run:
        raise RoadtwinError(f"{f}: has no evaluation on a selection folder (trained without --select)")
    sel = run["select"]
    return {**run, "I": sel["I"], "U": sel["U"], "eval": {"folder": sel["folder"], "stems": sel["stems"]}}


def load_runs(paths, as_trained: bool = False, on: str = "eval") -> list[dict]:
    """Run JSONs (files, or folders holding run_*.json); the same (arm, fraction, seed) twice must
    agree, and every run must be evaluated on the same frames. ``as_trained``: every run with its
    trained batch-norm statistics, so that runs with and without AdaBN compare. ``on="select"``:
    every run's evaluation on its selection folder instead of its evaluation folder."""
    if on not in ("eval", "select"):
        raise RoadtwinError(f"--on: eval or select, not {on!r}")
    if on == "select" and as_trained:
        raise RoadtwinError("--on select with --as-trained: the selection evaluation is after AdaBN only")
    files = []
    for p in map(Path, paths):
        files += sorted(p.glob("run_*.json")) if p.is_dir() else [p]
    if not files:
        raise RoadtwinError(f"no run_*.json in {', '.join(map(str, paths))}")
    runs, seen = [], {}
    for f in files:
        try:
            r = json.loads(f.read_text())
            key = (r["arm"], r["fraction"], r["seed"])
        except (ValueError, KeyError, TypeError):
            raise RoadtwinError(f"{f}: not a run JSON of bench/perception.py") from None
        if as_trained:
            r = _as_trained(r, f)
            r.pop("as_trained", None)
        if on == "select":
            r = _on_selection(r, f)
        if r["eval"]["stems"] != (runs[0]["eval"]["stems"] if runs else r["eval"]["stems"]):
            raise RoadtwinError(f"{f}: evaluated on other frames than {files[0]} ({r['eval']['folder']})")
        if runs and _comparable(r) != _comparable(runs[0]):
            a, b = _comparable(r), _comparable(runs[0])
            diff = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
            raise RoadtwinError(f"{f}: trained with another configuration than {runs[0]['_file']} ({', '.join(diff)})")
        two = [x for x in runs + [r] if x["arm"] in TWO_DOMAIN_ARMS]
        if len({bool(x["config"].get("domain_bn")) for x in two}) > 1:
            raise RoadtwinError(f"{f}: runs with and without --domain-bn among arms (b) and (c)")
        if key in seen:
            if seen[key]["I"] != r["I"]:
                raise RoadtwinError(f"{f}: run {r['name']} seed {r['seed']} given twice with other results")
            continue
        r["_file"] = str(f)
        seen[key] = r
        runs.append(r)
    steps = {r["steps"] for r in runs}
    if len(steps) > 1:
        raise RoadtwinError(f"runs with unequal optimizer steps {sorted(steps)}: every arm must get the same budget")
    return runs


def _pooled(runs: list[dict], seeds) -> tuple[np.ndarray, np.ndarray]:
    by = {r["seed"]: r for r in runs}
    return (sum(np.array(by[s]["I"]) for s in seeds), sum(np.array(by[s]["U"]) for s in seeds))


def _gain(summary: dict, key: str, arm: str, rs: list[dict], base: list[dict], n_boot: int, boot_seed: int,
          moonshot: bool = False) -> None:
    """The gain of runs ``rs`` over the real-only runs ``base`` on their common seeds (pooled)."""
    seeds = sorted({r["seed"] for r in rs} & {r["seed"] for r in base})
    if not seeds:
        return
    ia, ua = _pooled(base, seeds)
    ib, ub = _pooled(rs, seeds)
    g = bootstrap_gain(ia, ua, ib, ub, n_boot=n_boot, seed=boot_seed)
    for m in METRICS:
        g[m]["per_seed"] = [iou_table(*_pooled(rs, [s]))[m] - iou_table(*_pooled(base, [s]))[m] for s in seeds]
    summary["gains"][key] = {"arm": arm, "over": f"{base[0]['name']}", "seeds": seeds, "moonshot": moonshot, **g}


def _adabn(summary: dict, name: str, rs: list[dict], n_boot: int, boot_seed: int) -> None:
    """AdaBN's own effect on the runs ``rs`` (``--bn-stats real``): the same weights evaluated with
    the statistics of the real train frames against their trained ones, seeds pooled, paired."""
    as_trained = [{**r, "I": r["as_trained"]["I"], "U": r["as_trained"]["U"]} for r in rs]
    seeds = [r["seed"] for r in rs]
    g = bootstrap_gain(*_pooled(as_trained, seeds), *_pooled(rs, seeds), n_boot=n_boot, seed=boot_seed)
    for m in METRICS:
        g[m]["as_trained"] = iou_table(*_pooled(as_trained, seeds))[m]
        g[m]["per_seed"] = [iou_table(*_pooled(rs, [s]))[m] - iou_table(*_pooled(as_trained, [s]))[m] for s in seeds]
    summary.setdefault("adabn", {})[name] = {"seeds": seeds, **g}


def summarize(runs: list[dict], n_boot: int = 2000, boot_seed: int = 0) -> dict:
    groups: dict[str, list[dict]] = {}
    for r in sorted(runs, key=lambda r: ("abcde".index(r["letter"]), -(r["fraction"] or 0), r["seed"])):
        groups.setdefault(r["name"], []).append(r)
    first = runs[0]
    summary = {"eval": {"folder": first["eval"]["folder"], "frames": len(first["eval"]["stems"])},
               "steps_per_run": first["steps"], "config": first["config"], "device": first.get("device", ""),
               "gpu_seconds": round(sum(r["wall_seconds"] for r in runs), 1), "runs": {}, "gains": {},
               "bootstrap": {"resamples": n_boot, "seed": boot_seed, "level": 0.95, "unit": "evaluation frame"}}
    for name, rs in groups.items():
        tables = [iou_table(np.array(r["I"]), np.array(r["U"])) for r in rs]
        summary["runs"][name] = {
            "arm": rs[0]["arm"], "letter": rs[0]["letter"], "fraction": rs[0]["fraction"], "seeds": [r["seed"] for r in rs],
            "steps": rs[0]["steps"], "mix": rs[0].get("mix"), "steps_per_s": [r["steps_per_s"] for r in rs],
            **{m: {"mean": float(np.mean([t[m] for t in tables])),
                   "std": float(np.std([t[m] for t in tables], ddof=1)) if len(tables) > 1 else 0.0,
                   "per_seed": [t[m] for t in tables]} for m in METRICS}}
    real_fracs = sorted({r["fraction"] for r in runs if r["arm"] == "real"}, reverse=True)
    for name, rs in groups.items():
        arm, frac = rs[0]["arm"], rs[0]["fraction"]
        if arm == "real":
            continue
        for bf in (real_fracs if arm == "zeroshot" else [frac]):
            key = name if arm != "zeroshot" else f"zeroshot vs real@{round(bf * 100):g}%"
            _gain(summary, key, arm, rs, groups.get(f"real@{round(bf * 100):g}%", []), n_boot, boot_seed)
    for name, rs in groups.items():
        if all("as_trained" in r for r in rs):
            _adabn(summary, name, rs, n_boot, boot_seed)
    # the moonshot: a synthetic arm with a share of the real frames against (a) with all of them
    for name, rs in groups.items():
        if rs[0]["arm"] in ("pretrain", "mixed") and rs[0]["fraction"] < 1 and 1.0 in real_fracs:
            _gain(summary, f"{name} vs real@100%", rs[0]["arm"], rs, groups["real@100%"], n_boot, boot_seed,
                  moonshot=True)
    return summary


def by_road(runs: list[dict]) -> dict:
    """Per run name and road of the evaluation frames, IoU with the seeds' intersections and unions
    summed, and the road's share of the labelled pixels per class (from the unions: a class pixel
    the model misses is still in its union). Why: one road can hold most of a split's potholes
    and label them otherwise than the others (zero-shot: 2 pothole IoU on train's RS_290 strips)."""
    stems = runs[0]["eval"]["stems"]
    roads = [road_of(s) for s in stems]
    table = {}
    for name in dict.fromkeys(r["name"] for r in runs):
        rs = [r for r in runs if r["name"] == name]
        inter = sum(np.array(r["I"]) for r in rs)
        union = sum(np.array(r["U"]) for r in rs)
        table[name] = {}
        for road in sorted(set(roads), key=roads.index):
            idx = [k for k, x in enumerate(roads) if x == road]
            t = iou_table(inter[idx], union[idx])
            table[name][road] = {"frames": len(idx), **{c: t[c] for c in REPORTED},
                                 "pothole_union_share": float(union[idx, CLASSES.index("pothole")].sum()
                                                              / max(union[:, CLASSES.index("pothole")].sum(), 1))}
    return table


def by_road_markdown(table: dict) -> str:
    lines = ["Per road of the evaluation frames (seeds' intersections and unions summed); 'pothole share': the "
             "road's share of the pothole unions.", "",
             "| run | road | frames | pothole | crack | ego lane | pothole share |", "|---|---|---|---|---|---|---|"]
    for name, roads in table.items():
        for road, t in roads.items():
            lines.append(f"| {name} | {road} | {t['frames']} | {_pt(t['pothole'])} | {_pt(t['crack'])} | "
                         f"{_pt(t['ego_lane'])} | {100 * t['pothole_union_share']:.0f} % |")
    return "\n".join(lines) + "\n"


def compare_runs(paths_a, paths_b, n_boot: int = 2000, boot_seed: int = 0, on: str = "eval") -> dict:
    """Runs of two configurations (e.g. with and without an option) paired by (arm, fraction, seed):
    per run name present in both, the seeds both have, each side's mean and the paired bootstrap
    gain of B over A (seeds pooled). Why: an option's effect on one arm, which ``report`` (every
    arm against real only, one configuration) cannot show. Both sides on the same frames."""
    a, b = load_runs(paths_a, on=on), load_runs(paths_b, on=on)
    if a[0]["eval"]["stems"] != b[0]["eval"]["stems"]:
        raise RoadtwinError(f"{b[0]['_file']}: evaluated on other frames than {a[0]['_file']}")
    ka, kb = _comparable(a[0]), _comparable(b[0])

    def mean(rs: list[dict]) -> dict:
        tables = [iou_table(np.array(r["I"]), np.array(r["U"])) for r in rs]
        return {m: float(np.mean([t[m] for t in tables])) for m in METRICS}

    rows = {}
    for name in dict.fromkeys(r["name"] for r in a):
        ra = {r["seed"]: r for r in a if r["name"] == name}
        rb = {r["seed"]: r for r in b if r["name"] == name}
        seeds = sorted(ra.keys() & rb.keys())
        if not seeds:
            continue
        rows[name] = {"seeds": seeds, "a": mean([ra[s] for s in seeds]), "b": mean([rb[s] for s in seeds]),
                      "gain": bootstrap_gain(*_pooled(list(ra.values()), seeds), *_pooled(list(rb.values()), seeds),
                                             n_boot, boot_seed)}
    if not rows:
        raise RoadtwinError("compare: no run (arm, fraction, seed) is on both sides")
    differ = {k: [ka.get(k), kb.get(k)] for k in sorted(ka.keys() | kb.keys()) if ka.get(k) != kb.get(k)}
    return {"a": a[0]["_file"], "b": b[0]["_file"], "on": on, "folder": a[0]["eval"]["folder"], "differ": differ,
            "rows": rows}


def differ_text(cmp: dict) -> str:
    """What tells ``compare``'s two configurations apart, as "key A -> B, ..."; where the recorded
    configurations agree (e.g. two synthetic sets), the folders the runs came from."""
    return (", ".join(f"{k} {va} -> {vb}" for k, (va, vb) in cmp["differ"].items())
            or f"the same configuration: {Path(cmp['a']).parent.name} -> {Path(cmp['b']).parent.name}")


def compare_where(cmp: dict) -> str:
    """Which frames ``compare`` scored: "the selection frames (`folder`)" or the evaluation ones."""
    return f"the {'selection' if cmp.get('on') == 'select' else 'evaluation'} frames (`{cmp.get('folder', '?')}`)"


def compare_markdown(cmp: dict) -> str:
    lines = [f"B over A ({differ_text(cmp)}); on {compare_where(cmp)}, paired bootstrap 95 % "
             "interval over them, seeds pooled.", "",
             "| run | seeds | " + " | ".join(f"{m} A / B: gain [interval]" for m in METRICS) + " |",
             "|---|---|" + "---|" * len(METRICS)]
    for name, row in cmp["rows"].items():
        cells = [f"{_pt(row['a'][m])} / {_pt(row['b'][m])}: {row['gain'][m]['gain'] * 100:+.1f} "
                 f"[{_pt(row['gain'][m]['lo'])}, {_pt(row['gain'][m]['hi'])}]" for m in METRICS]
        lines.append(f"| {name} | {', '.join(map(str, row['seeds']))} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _pt(v) -> str:
    return "–" if v is None or not np.isfinite(v) else f"{100 * v:.1f}"


def markdown(summary: dict) -> str:
    cols = list(METRICS)
    head = ["run", "seeds"] + [c.replace("_fg", " w/o bg").replace("_", " ") for c in cols] + ["mix (CV)"]
    lines = [f"Evaluation: `{summary['eval']['folder']}` ({summary['eval']['frames']} frames); "
             f"{summary['steps_per_run']} optimizer steps in every run; IoU in points, mean ± std over seeds."
             + (" Every run with its trained batch-norm statistics (`--as-trained`: AdaBN's evaluations set aside)."
                if summary["config"].get("bn_stats", "train") == "train" and summary.get("as_trained") else ""), "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, t in summary["runs"].items():
        mix = t.get("mix")
        mix_text = f"{mix['ratio']:g} synthetic, {mix['schedule']}" if mix else ""
        lines.append(f"| ({t['letter']}) {name} | {len(t['seeds'])} | "
                     + " | ".join(f"{_pt(t[c]['mean'])} ± {_pt(t[c]['std'])}" for c in cols) + f" | {mix_text} |")
    if summary["gains"]:
        n = summary["bootstrap"]["resamples"]
        lines += ["", f"Gain over (a) at the same fraction and seeds (seeds pooled), paired bootstrap 95 % "
                  f"interval over val frames ({n} resamples); 'vs real@100%': the moonshot, a share of the real "
                  "frames + synthetic against all real frames:", "",
                  "| run | over | " + " | ".join(c.replace("_fg", " w/o bg").replace("_", " ") for c in cols) + " |",
                  "|" + "---|" * (len(cols) + 2)]
        for name, g in summary["gains"].items():
            lines.append(f"| {name} | {g['over']} | " + " | ".join(
                f"{'+' if g[c]['gain'] >= 0 else ''}{_pt(g[c]['gain'])} [{_pt(g[c]['lo'])}, {_pt(g[c]['hi'])}]"
                for c in cols) + " |")
    if summary.get("adabn"):
        lines += ["", "AdaBN (`--bn-stats real`): the same weights with the batch-norm statistics of their real train "
                  "frames against their trained statistics (seeds pooled; paired bootstrap as above). The tables "
                  "above are with AdaBN.", "",
                  "| run | " + " | ".join(f"{c.replace('_fg', ' w/o bg').replace('_', ' ')}: as trained -> AdaBN gain"
                                         for c in cols) + " |", "|" + "---|" * (len(cols) + 1)]
        for name, g in summary["adabn"].items():
            lines.append(f"| {name} | " + " | ".join(
                f"{_pt(g[c]['as_trained'])} -> {'+' if g[c]['gain'] >= 0 else ''}{_pt(g[c]['gain'])} "
                f"[{_pt(g[c]['lo'])}, {_pt(g[c]['hi'])}]" for c in cols) + " |")
    return "\n".join(lines) + "\n"
