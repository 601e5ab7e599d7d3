"""Learning curves: every checkpoint of one or more runs evaluated on a task (``qlap curve``).

The protocol is §7.2 of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions
in a Developing Agent*, PhD dissertation, UT Austin, 2010: the agent saved every 10,000 steps
is given the task's goal with learning off, for a number of trials. Each evaluation is
:func:`qlap_runtime.agent_run.evaluate`, the function behind ``qlap eval``, run in a spawned
worker process. One run is drawn with the standard error over its trials; several runs (seeds)
with their mean and the standard error across runs, as Figs. 7.2–7.4 ("all error bars are
standard error", §7.3). The random policy of the same world, task, trials and seed is the
dashed line.

``curve.csv`` keeps every evaluation; one already there for the same run, checkpoint step,
world, task, trials and seed is not recomputed, so an interrupted curve resumes. ``every``
(``--every N``) thins the checkpoints to those whose step is a multiple of N, plus each run's
last, to make curves of many seeds and tasks affordable.
"""

from __future__ import annotations

import csv
import io
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..qlap.checkpoint import atomic_write_bytes
from .runs import (
    AnalysisError,
    Checkpoint,
    find_checkpoints,
    run_labels,
    run_world,
    save_png,
)

__all__ = [
    "CSV_FIELDS",
    "RANDOM_RUN",
    "CurvePoint",
    "CurveRow",
    "EvalJob",
    "aggregate",
    "evaluate_job",
    "format_table",
    "main_curve",
    "plot_curve",
    "read_rows",
    "select_every",
    "write_rows",
]

RANDOM_RUN = "random"
"""The ``run`` of the random policy's row in curve.csv (its ``step`` is empty)."""

CSV_FIELDS = ("run", "step", "task", "mean_reward", "stderr", "success_rate", "trials", "seed",
              "world", "policy", "checkpoint")
"""The columns of curve.csv (docs/analysis.md)."""

Key = tuple[str, str, int | None, str, str, int, int]


@dataclass(frozen=True)
class CurveRow:
    """One evaluation: a checkpoint (or the random policy) on a task."""

    run: str
    """The run's label, or :data:`RANDOM_RUN`."""
    step: int | None
    """Steps the agent had observed; None for the random policy."""
    task: str
    mean_reward: float
    """Mean reward per trial (§7.2)."""
    stderr: float
    """Standard error of the mean over the trials."""
    success_rate: float
    trials: int
    seed: int
    """Seed of the trials (the same for every checkpoint: the same trial set-ups)."""
    world: str
    """World spec the trials ran in."""
    policy: str
    """``qlap`` or ``random``."""
    checkpoint: str
    """``step-NNNNNNN``, ``final`` or empty."""

    @property
    def key(self) -> Key:
        return (self.policy, self.run, self.step, self.world, self.task, self.trials, self.seed)

    def to_csv(self) -> dict[str, str]:
        return {k: "" if v is None else str(v) for k, v in asdict(self).items()}

    @classmethod
    def from_csv(cls, d: dict[str, str]) -> CurveRow:
        return cls(run=d["run"], step=int(d["step"]) if d["step"] else None, task=d["task"],
                   mean_reward=float(d["mean_reward"]), stderr=float(d["stderr"]),
                   success_rate=float(d["success_rate"]), trials=int(d["trials"]),
                   seed=int(d["seed"]), world=d["world"], policy=d["policy"],
                   checkpoint=d["checkpoint"])


def read_rows(path: Path) -> list[CurveRow]:
    """The rows of a curve.csv (none if it does not exist)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    except UnicodeDecodeError as exc:
        raise AnalysisError(f"{path}: not a curve.csv (not UTF-8 text: {exc.reason} at byte "
                            f"{exc.start})") from None
    reader = csv.DictReader(io.StringIO(text))
    if reader.fieldnames is None or not set(CSV_FIELDS) <= set(reader.fieldnames):
        raise AnalysisError(f"{path}: not a curve.csv (columns {', '.join(CSV_FIELDS)})")
    try:
        return [CurveRow.from_csv(d) for d in reader]
    except (KeyError, ValueError, TypeError) as exc:
        raise AnalysisError(f"{path}: unreadable row ({exc})") from None


def write_rows(path: Path, rows: Sequence[CurveRow]) -> None:
    """Write curve.csv atomically: the random policy first, then by run, task and step."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    order = sorted(rows, key=lambda r: (r.policy != "random", r.run, r.task, r.world,
                                        r.trials, r.seed, r.step or 0))
    writer.writerows(r.to_csv() for r in order)
    atomic_write_bytes(Path(path), buf.getvalue().encode())


@dataclass(frozen=True)
class EvalJob:
    """What a worker process evaluates (plain values: it crosses a process boundary)."""

    checkpoint: str | None
    """Agent checkpoint directory; None for the random policy."""
    world: str
    task: str
    trials: int
    seed: int


def evaluate_job(job: EvalJob) -> dict[str, Any]:
    """Run one evaluation in this process: make the world, call ``evaluate`` (as ``qlap eval``)."""
    import worlds

    from ..agent_run import evaluate

    policy, checkpoint = ("qlap", job.checkpoint) if job.checkpoint else ("random", "")
    world = worlds.make(job.world)
    t0 = time.perf_counter()
    try:
        res = evaluate(checkpoint, world, job.task, job.trials, job.seed, policy)
    finally:
        world.close()
    return {"mean_reward": res["mean_reward"], "stderr": res["stderr_reward"],
            "success_rate": res["success_rate"], "trials": res["n_trials"],
            "seconds": time.perf_counter() - t0}


def evaluate_job_json(job: str) -> str:
    """:func:`evaluate_job` across a process boundary: the job and its result as JSON text
    (what crosses to a worker process is a string, never a pickled object)."""
    return json.dumps(evaluate_job(EvalJob(**json.loads(job))))


@dataclass(frozen=True)
class CurvePoint:
    """The curve at one step: over the trials of one run, or over several runs."""

    step: int
    mean_reward: float
    stderr: float
    """One run: the standard error over its trials; several: across the runs' means (NaN
    when only one run has this step)."""
    success_rate: float
    """Mean over the runs."""
    runs: dict[str, float]
    """Each run's mean reward at this step."""


def aggregate(rows: Sequence[CurveRow], n_runs: int) -> list[CurvePoint]:
    """The curve of ``rows`` (the checkpoint rows of one task, world, trials and seed).

    With one run, each point is that run's evaluation; with ``n_runs`` > 1, the mean of the
    runs that have the step and the standard error s/√n across them (§7.3, Figs. 7.2–7.4).
    """
    by_step: dict[int, list[CurveRow]] = {}
    for r in rows:
        if r.step is not None:
            by_step.setdefault(r.step, []).append(r)
    points = []
    for step in sorted(by_step):
        group = sorted(by_step[step], key=lambda r: r.run)
        means = np.array([r.mean_reward for r in group], dtype=float)
        if n_runs == 1 and len(group) == 1:
            stderr = group[0].stderr
        elif len(group) > 1:
            stderr = float(means.std(ddof=1) / math.sqrt(len(group)))
        else:
            stderr = math.nan
        points.append(CurvePoint(step, float(means.mean()), stderr,
                                 float(np.mean([r.success_rate for r in group])),
                                 {r.run: r.mean_reward for r in group}))
    return points


def plot_curve(points: Sequence[CurvePoint], baseline: CurveRow | None, path: Path,
               title: str, n_runs: int) -> None:
    """Write the curve to a PNG (matplotlib's Agg canvas): mean reward against steps with
    standard-error bars, each run faintly when there are several, the random policy dashed."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.5))
    ax = fig.subplots()
    steps = [p.step for p in points]
    if n_runs > 1:
        for i, run in enumerate(sorted({r for p in points for r in p.runs})):
            xs = [p.step for p in points if run in p.runs]
            ax.plot(xs, [p.runs[run] for p in points if run in p.runs], color="0.75",
                    linewidth=0.8, label="each run" if i == 0 else None)
    yerr = [0.0 if math.isnan(p.stderr) else p.stderr for p in points]
    label = ("QLAP (± s.e. over trials)" if n_runs == 1
             else f"QLAP, mean of {n_runs} runs (± s.e. across runs)")
    ax.errorbar(steps, [p.mean_reward for p in points], yerr=yerr, fmt="o-", capsize=3,
                color="C0", label=label)
    if baseline is not None:
        ax.axhline(baseline.mean_reward, linestyle="--", color="C3",
                   label=f"random policy ({baseline.mean_reward:.2f})")
    ax.set_xlabel("agent steps")
    ax.set_ylabel("mean reward per trial")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_png(fig, path)


def format_table(points: Sequence[CurvePoint], baseline: CurveRow | None,
                 rows: Sequence[CurveRow], runs: Sequence[str]) -> str:
    """The curve as a text table (one line per step; with several runs, each run's mean)."""
    lines = []
    if len(runs) == 1:
        names = {r.step: r.checkpoint for r in rows}
        lines.append(f"{'step':>9}  {'checkpoint':<13} {'mean reward':>11} {'s.e.':>7} "
                     f"{'success':>7}")
        for p in points:
            lines.append(f"{p.step:>9}  {names.get(p.step, ''):<13} {p.mean_reward:>11.3f} "
                         f"{p.stderr:>7.3f} {p.success_rate:>7.2f}")
    else:
        width = max(8, *(len(r) for r in runs))
        lines.append(f"{'step':>9}  {'runs':>4} {'mean reward':>11} {'s.e.':>7} {'success':>7}  "
                     + " ".join(f"{r:>{width}}" for r in runs))
        for p in points:
            cells = " ".join(f"{p.runs[r]:>{width}.3f}" if r in p.runs else f"{'':>{width}}"
                             for r in runs)
            se = "" if math.isnan(p.stderr) else f"{p.stderr:.3f}"
            lines.append(f"{p.step:>9}  {len(p.runs):>4} {p.mean_reward:>11.3f} {se:>7} "
                         f"{p.success_rate:>7.2f}  {cells}")
    if baseline is not None:
        lines.append(f"random policy: {baseline.mean_reward:.3f} ± {baseline.stderr:.3f} "
                     f"(s.e.), success rate {baseline.success_rate:.2f}")
    return "\n".join(lines)


def _check_task(world_spec: str, task: str) -> None:
    import worlds

    try:
        world = worlds.make(world_spec)
    except (ValueError, ImportError, AttributeError, TypeError) as exc:
        raise AnalysisError(f"world {world_spec!r}: {exc}") from None
    try:
        if task not in world.tasks:
            from worlds.evaluate import no_task

            raise AnalysisError(no_task(world_spec, task, world.tasks))
    finally:
        world.close()


def _collect(run_dirs: list[Path], labels: list[str],
             world: str | None) -> tuple[list[Checkpoint], str]:
    """Every checkpoint of the runs, and their one world spec."""
    checkpoints: list[Checkpoint] = []
    specs = set()
    for run_dir, label in zip(run_dirs, labels, strict=True):
        if run_dir.is_file():
            raise AnalysisError(f"{run_dir}: a file, not a run directory")
        if not run_dir.is_dir():
            raise AnalysisError(f"{run_dir}: no such run directory")
        found = find_checkpoints(run_dir, label)
        if not found and (run_dir / "agent.json").is_file():
            holder = run_dir.resolve().parent
            raise AnalysisError(
                f"{run_dir} is a checkpoint, not a run directory: give "
                + (f"the run that holds it ({holder.parent})" if holder.name == "checkpoints"
                   else "a run directory (one with checkpoints/)"))
        if not found and run_dir.name == "checkpoints":
            raise AnalysisError(f"{run_dir} holds a run's checkpoints: give the run directory "
                                f"({run_dir.resolve().parent})")
        if not found:
            raise AnalysisError(f"{run_dir}: no agent checkpoints under checkpoints/")
        specs.add(run_world(run_dir, found, world))
        checkpoints += found
    if len(specs) > 1:
        raise AnalysisError(f"the runs are in different worlds ({', '.join(sorted(specs))}); "
                            "one curve compares runs of one world")
    return checkpoints, specs.pop()


def select_every(checkpoints: Sequence[Checkpoint], every: int | None,
                 at: Sequence[int] = ()) -> list[Checkpoint]:
    """The checkpoints whose step is a multiple of ``every`` or one of ``at``, plus each run's
    last one (all of them when ``every`` is None)."""
    if every is None:
        return list(checkpoints)
    if every < 1:
        raise AnalysisError(f"--every must be a positive number of steps, got {every}")
    last: dict[str, int] = {}
    for c in checkpoints:
        last[c.run] = max(last.get(c.run, c.step), c.step)
    extra = set(at)
    steps = sorted({c.step for c in checkpoints})
    if missing := sorted(extra - set(steps)):
        raise AnalysisError(f"--at {' '.join(map(str, missing))}: no run has a checkpoint of "
                            f"that step (the steps: {', '.join(f'{s:,}' for s in steps)})")
    return [c for c in checkpoints
            if c.step % every == 0 or c.step in extra or c.step == last[c.run]]


def _run_pending(pending: list[tuple[Key, EvalJob, Checkpoint | None]], jobs: int,
                 done: dict[Key, CurveRow], csv_path: Path,
                 echo: Callable[[str], None]) -> int:
    """Evaluate in spawned worker processes; record and print each result as it comes.
    Returns the number of failed evaluations."""
    failures = 0
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(pending)),
                               mp_context=multiprocessing.get_context("spawn"))
    try:
        futures: dict[Future[str], tuple[Key, EvalJob, Checkpoint | None]] = {
            pool.submit(evaluate_job_json, json.dumps(asdict(job))): (key, job, c)
            for key, job, c in pending}
        for i, fut in enumerate(as_completed(futures), 1):
            key, job, c = futures[fut]
            what = f"{c.run} {c.name} (step {c.step})" if c else "random policy"
            try:
                res = json.loads(fut.result())
            except Exception as exc:   # a bad checkpoint must not stop the others
                failures += 1
                echo(f"[{i}/{len(pending)}] {what}: FAILED: {type(exc).__name__}: {exc}")
                continue
            row = done[key] = CurveRow(
                run=c.run if c else RANDOM_RUN, step=c.step if c else None, task=job.task,
                mean_reward=float(res["mean_reward"]), stderr=float(res["stderr"]),
                success_rate=float(res["success_rate"]), trials=int(res["trials"]),
                seed=job.seed, world=job.world, policy="qlap" if c else "random",
                checkpoint=c.name if c else "")
            write_rows(csv_path, list(done.values()))
            echo(f"[{i}/{len(pending)}] {what} {job.task}: mean reward {row.mean_reward:.3f} "
                 f"± {row.stderr:.3f}, success {row.success_rate:.2f} "
                 f"({res['seconds']:.1f} s)")
    except BaseException:
        # Ctrl-C (or an error): the evaluations still running are stopped, not waited for —
        # their workers are this process's children (curve.csv keeps what finished).
        pool.shutdown(wait=False, cancel_futures=True)
        for child in multiprocessing.active_children():
            child.terminate()
        raise
    pool.shutdown()
    return failures


def main_curve(run_dirs: Sequence[Path], task: str, trials: int = 100, jobs: int | None = None,
               seed: int = 0, out: Path | None = None, world: str | None = None,
               echo: Callable[[str], None] = print, every: int | None = None,
               at: Sequence[int] = ()) -> int:
    """``qlap curve``: evaluate, write curve.csv and curve.png, print progress and the table.

    ``every``: evaluate only the checkpoints whose step is a multiple of it or one of ``at``,
    plus each run's last (:func:`select_every`); None: all of them.

    Returns 0, or 1 when an evaluation failed (the others are written). Raises
    :class:`AnalysisError` for unusable arguments.
    """
    run_dirs = [Path(d) for d in run_dirs]
    if not run_dirs:
        raise AnalysisError("give at least one run directory")
    if len(run_dirs) > 1 and out is None:
        raise AnalysisError("several run directories need --out DIR for the joint curve")
    out_dir = Path(out) if out is not None else run_dirs[0]
    labels = run_labels(run_dirs)
    checkpoints, spec = _collect(run_dirs, labels, world)
    n_found = len(checkpoints)
    checkpoints = select_every(checkpoints, every, at)
    _check_task(spec, task)

    wanted: list[tuple[Key, EvalJob, Checkpoint | None]] = [
        (("random", RANDOM_RUN, None, spec, task, trials, seed),
         EvalJob(None, spec, task, trials, seed), None)]
    wanted += [(("qlap", c.run, c.step, spec, task, trials, seed),
                EvalJob(str(c.path), spec, task, trials, seed), c) for c in checkpoints]
    csv_path = out_dir / "curve.csv"
    done: dict[Key, CurveRow] = {r.key: r for r in read_rows(csv_path)}
    if out is not None:                       # each run's own curve.csv is a cache too
        keys = {key for key, _, _ in wanted}
        for run_dir, label in zip(run_dirs, labels, strict=True):
            for r in read_rows(run_dir / "curve.csv"):
                r = replace(r, run=label) if r.policy == "qlap" else r
                if r.key in keys:
                    done.setdefault(r.key, r)
    pending = [w for w in wanted if w[0] not in done]
    jobs = min(jobs or os.cpu_count() or 1, max(1, len(pending)))
    chosen = (f"{len(checkpoints)} checkpoints" if every is None else
              f"{len(checkpoints)} of {n_found} checkpoints (steps multiple of {every:,}, and "
              "each run's last)")
    echo(f"{chosen} of {len(run_dirs)} run(s) on {spec} {task}, "
         f"{trials} trials, seed {seed}: {len(wanted) - len(pending)} of {len(wanted)} "
         f"evaluations (the random policy's included) already in {csv_path}; "
         + (f"{len(pending)} to run on {jobs} worker process(es)" if pending
            else "nothing to run"))
    failures = _run_pending(pending, jobs, done, csv_path, echo) if pending else 0
    write_rows(csv_path, list(done.values()))

    rows = [done[key] for key, _, c in wanted if c is not None and key in done]
    baseline = done.get(wanted[0][0])
    points = aggregate(rows, len(run_dirs))
    wrote = [str(csv_path)]
    if points:
        who = ", ".join(labels) if len(labels) <= 4 else f"{len(labels)} runs"
        title = f"{task} on {spec}: {who}; {trials} trials a checkpoint, seed {seed}"
        try:
            plot_curve(points, baseline, out_dir / "curve.png", title, len(run_dirs))
            wrote.append(str(out_dir / "curve.png"))
        except ImportError:
            echo("matplotlib is missing (pip install -e .[experiments]): no curve.png")
    echo("")
    echo(format_table(points, baseline, rows, labels))
    echo(f"\nwrote {', '.join(wrote)}")
    return 1 if failures else 0
