"""``bench/perception.py suite``: a list of (arm, fraction, seed) runs as N processes sharing one
GPU, each writing its own run JSON, so a whole table takes few device calls.

Jobs: the synthetic phase 1 of each seed (shared by arms b and e), the cross-validation of the
mixed arm (one job per fraction and grid point, its folds inside, each fold with its own set
under --cv-synthetic; the parent picks the point once a fraction's jobs are in) and the runs. A
job starts when what it needs exists; jobs whose output already exists (in --out or a --reuse
folder) are skipped, so a table too long for one call is finished by the next call with the
earlier outputs carried back. With --time-budget a
job starts only if, at the pace of the jobs done so far, it ends in time, so a call ends with
whole runs only. With several GPUs (--gpus) each job starts on the card with the fewest jobs
running (its CUDA_VISIBLE_DEVICES), so one suite fills a machine. Each job is
``perception.py _job COMMON SPEC`` with its log in OUT/logs/; the parent prints each one's wall
time and steps/s as it ends.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from _perception_arms import run_name
from roadtwin_core.errors import RoadtwinError
from _perception_cv import choose, cv_path, set_names, write_json

HERE = Path(__file__).resolve().parent


@dataclass
class Job:
    kind: str                     # pretrain | cv | run
    spec: dict
    output: Path
    needs: list = field(default_factory=list)
    label: str = ""
    steps: int = 0                # optimizer steps it trains (pace estimate)


def pct(fraction: float) -> str:
    return f"{round(fraction * 100):g}"


def plan(arms, fractions, seeds, out: Path, shared: Path, n_points: int, cv_needed: bool) -> tuple[list[Job], dict]:
    """Every job of the table, dependencies first (longest chains lead)."""
    jobs: list[Job] = []
    pre = {}
    if any(a in ("pretrain", "zeroshot") for a in arms):
        for s in seeds:
            pre[s] = shared / f"pretrain_done_seed{s}.json"
            jobs.append(Job("pretrain", {"seed": s}, pre[s], label=f"synthetic phase 1 seed {s}"))
    cv_parts = {}
    if "mixed" in arms and cv_needed:
        for f in fractions:
            cv_parts[f] = []
            for p in range(n_points):
                o = shared / "cv_parts" / f"cv_{pct(f)}_p{p}.json"
                cv_parts[f].append(o)
                jobs.append(Job("cv", {"fraction": f, "point": p}, o, label=f"cv {pct(f)}% grid point {p}"))
    order = [a for a in ("pretrain", "zeroshot", "mixed", "real", "paste") if a in arms]
    for arm in order:
        for s in seeds:
            for f in ([None] if arm == "zeroshot" else fractions):
                needs = [pre[s]] if arm in ("pretrain", "zeroshot") else []
                if arm == "mixed" and cv_needed:
                    needs = [cv_path(shared, f)]
                name = f"run_{arm}_{'na' if f is None else pct(f)}_seed{s}.json"
                jobs.append(Job("run", {"arm": arm, "fraction": f, "seed": s}, out / name, needs,
                                label=f"{run_name(arm, f)} seed {s}"))
    return jobs, cv_parts


def _reuse(job: Job, out: Path, reuse: list[Path]) -> bool:
    """Copy a finished output (and its companions) from a --reuse folder; True when it exists."""
    if job.output.exists():
        return True
    rel = job.output.relative_to(out)
    for r in reuse:
        src = Path(r) / rel
        if job.kind == "pretrain" and not list(src.parent.glob(f"pretrain_seed{job.spec['seed']}_*.pt")):
            continue                             # its checkpoint did not travel: train it again
        if src.exists():
            job.output.parent.mkdir(parents=True, exist_ok=True)
            for comp in src.parent.glob(src.stem + ".*"):
                shutil.copy2(comp, job.output.parent / comp.name)
            if job.kind == "pretrain":
                for ck in src.parent.glob(f"pretrain_seed{job.spec['seed']}_*.pt"):
                    shutil.copy2(ck, job.output.parent / ck.name)
            return True
    return False


def _prune(pending: list[Job], out: Path) -> list[Job]:
    """Drop the pretrain and CV jobs whose runs are all done already."""
    runs = [j for j in pending if j.kind == "run"]
    keep = []
    for j in pending:
        if j.kind == "pretrain" and not any(str(j.output) in map(str, r.needs) for r in runs):
            continue
        if j.kind == "cv" and (cv_path(out / "shared", j.spec["fraction"]).exists() or not any(
                r.spec["arm"] == "mixed" and r.spec["fraction"] == j.spec["fraction"] for r in runs)):
            continue
        keep.append(j)
    return keep


def gpu_ids(count: int, visible: str | None) -> list[str] | None:
    """The cards jobs are spread over: the first ``count`` of CUDA_VISIBLE_DEVICES (or 0..count-1);
    None for one card (jobs inherit the environment)."""
    if count <= 1:
        return None
    ids = [v.strip() for v in visible.split(",") if v.strip()] if visible else [str(i) for i in range(count)]
    if len(ids) < count:
        raise RoadtwinError(f"--gpus {count}: CUDA_VISIBLE_DEVICES={visible} names {len(ids)} card(s)")
    return ids[:count]


def least_loaded(gpus: list[str], busy: list[str]) -> str:
    """The card with the fewest running jobs (the first such, so a start is deterministic)."""
    return min(gpus, key=lambda g: (busy.count(g), gpus.index(g)))


@dataclass
class Running:
    """A job's process, and how many jobs shared its card while it ran (summed over the checks)."""
    job: Job
    proc: subprocess.Popen
    start: float
    log: Any
    gpu: str | None
    shared_sum: int = 0
    checks: int = 0

    def mean_sharing(self) -> float:
        return self.shared_sum / self.checks if self.checks else 1.0


class Pace:
    """Seconds an optimizer step takes, per job sharing the card: jobs on one GPU share it, so a
    job that ran beside two others took ~3x as long a step as it would alone. Each finished job
    gives its wall seconds per step over the mean number of jobs on its card while it ran; the
    slowest of these (the estimate stays on the safe side) times the jobs its card will hold
    predicts a new job's wall time."""

    def __init__(self):
        self.per_step_per_job: float | None = None

    def observe(self, steps: int, wall: float, mean_sharing: float) -> None:
        if steps > 0:
            value = wall / steps / max(mean_sharing, 1.0)
            self.per_step_per_job = max(self.per_step_per_job or 0.0, value)

    def predict(self, steps: int, sharing: int) -> float | None:
        """Wall seconds of a ``steps`` job on a card that ``sharing`` jobs (itself included) share; None: no pace yet."""
        return None if self.per_step_per_job is None else steps * self.per_step_per_job * max(sharing, 1)


def _summary_line(job: Job, wall: float) -> str:
    try:
        r = json.loads(job.output.read_text())
    except (OSError, ValueError):
        return f"{job.label}: {wall:.0f} s"
    steps = r.get("steps", 0)
    sec = r.get("train_seconds") or r.get("seconds") or wall
    return f"{job.label}: {wall:.0f} s wall, {steps} steps, {steps / sec:.1f} steps/s" if steps else f"{job.label}: {wall:.0f} s"


def run_suite(jobs: list[Job], cv_parts: dict, common: Path, out: Path, parallel: int, budget: float | None,
              reuse: list[Path], metric: str, log=print, gpus: list[str] | None = None) -> int:
    """Run the jobs, at most ``parallel`` at once; returns the number that failed or never started."""
    t0 = time.perf_counter()
    for f in cv_parts:                       # a choice already made travels with --reuse
        target = cv_path(out / "shared", f)
        for r in reuse:
            src = cv_path(Path(r) / "shared", f)
            if not target.exists() and src.exists():
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(src, target)
    pending = _prune([j for j in jobs if not _reuse(j, out, reuse)], out)
    log(f"suite: {len(jobs)} jobs, {len(jobs) - len(pending)} already done, {len(pending)} to run, "
        f"{parallel} in parallel" + (f" over GPUs {','.join(gpus)}" if gpus else "")
        + (f", every job to end within {budget:.0f} s" if budget else ""))
    running: list = []
    pace = Pace()
    failed: list[Job] = []
    done_count = len(jobs) - len(pending)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    while pending or running:
        for entry in list(running):
            job, proc = entry.job, entry.proc
            if proc.poll() is None:
                entry.shared_sum += sum(1 for r in running if r.gpu == entry.gpu)   # jobs on its card, itself included
                entry.checks += 1
                continue
            entry.log.close()
            running.remove(entry)
            wall = time.perf_counter() - entry.start
            if proc.returncode == 0 and job.output.exists():
                done_count += 1
                if job.steps:                    # wall seconds per step and job sharing its card
                    pace.observe(job.steps, wall, entry.mean_sharing())
                log(f"[{done_count}/{len(jobs)}] {_summary_line(job, wall)}")
            else:
                failed.append(job)
                tail = (out / "logs" / f"{job.output.stem}.log").read_text().strip().splitlines()[-1:] or [""]
                log(f"FAILED {job.label} (exit {proc.returncode}): {tail[0]}")
        for f, parts in cv_parts.items():
            target = cv_path(out / "shared", f)
            if not target.exists() and all(p.exists() for p in parts):
                rec = choose(f, [json.loads(p.read_text()) for p in parts], metric)
                given = json.loads(common.read_text())         # the final run's set (+ the per-fold CV sets)
                rec.update(set_names(given.get("synthetic"), given.get("cv_synthetic")))
                write_json(target, rec)
                log(f"mixed arm at {pct(f)}%: CV chose ratio {rec['chosen']['ratio']:g}, {rec['chosen']['schedule']}")
        elapsed = time.perf_counter() - t0
        out_of_time = budget is not None and elapsed > budget
        dead = {str(j.output) for j in failed}
        for job in list(pending):
            if any(str(n) in dead for n in job.needs) or (job.kind == "run" and job.spec["arm"] == "mixed"
                                                           and any(str(p) in dead for p in cv_parts.get(job.spec["fraction"], []))):
                pending.remove(job)
                failed.append(job)
                log(f"SKIPPED {job.label}: what it needs failed")
                continue
            if len(running) >= parallel or out_of_time:
                break
            gpu = least_loaded(gpus, [r.gpu for r in running]) if gpus else None
            wall = pace.predict(job.steps, 1 + sum(1 for r in running if r.gpu == gpu))
            if budget is not None and wall is not None and elapsed + wall + 20 > budget:
                continue                         # would not end in time at the pace seen so far
            if all(Path(n).exists() for n in job.needs):
                pending.remove(job)
                spec = {"kind": job.kind, **job.spec, "output": str(job.output)}
                fh = open(out / "logs" / f"{job.output.stem}.log", "w")
                env = {**os.environ, "PYTHONUNBUFFERED": "1"}
                if gpu is not None:
                    env["CUDA_VISIBLE_DEVICES"] = gpu
                proc = subprocess.Popen([sys.executable, str(HERE / "perception.py"), "_job", str(common), json.dumps(spec)],
                                        stdout=fh, stderr=subprocess.STDOUT, env=env)
                running.append(Running(job, proc, time.perf_counter(), fh, gpu))
        if not running and pending and not any(all(Path(n).exists() for n in j.needs) for j in pending):
            log(f"suite: {len(pending)} job(s) wait for outputs no job makes (e.g. {pending[0].needs[0]})")
            break
        if budget is not None and not running and (out_of_time or not any(
                elapsed + (pace.predict(j.steps, 1) or 0) + 20 <= budget for j in pending)):
            break
        time.sleep(0.2)
    left = len(pending)
    log(f"suite: {done_count}/{len(jobs)} done in {time.perf_counter() - t0:.0f} s"
        + (f"; {len(failed)} failed" if failed else "") + (f"; {left} not started (--time-budget): run the same "
                                                           f"command again with --reuse" if left else ""))
    return len(failed) + left
