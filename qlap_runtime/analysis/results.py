"""The results page (``docs/results.md``): seeds run, curves, knowledge, DBN growth, speed.

``scripts/learning_results.py`` is the command; this module does the work so that its pieces
can be tested. It runs the missing seeds (``qlap run --headless --placement sync``, resumable),
evaluates the curves of every task over all seeds (:func:`.curve.main_curve`), reads the
knowledge (:func:`.report.report_data`) and writes a Markdown page with its images, judged
against the targets of :mod:`.reference_values`. The reference is J. Mugan, *Autonomous
Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD dissertation, UT
Austin, 2010.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..qlap.checkpoint import atomic_write_bytes
from ..telemetry import pretty
from . import reference_values as ref
from .curve import (
    RANDOM_RUN,
    CurvePoint,
    CurveRow,
    aggregate,
    main_curve,
    read_rows,
    select_every,
)
from .markdown import pm, table
from .report import report_data
from .runs import AnalysisError, find_checkpoints, read_summary, run_labels, run_world
from .timeline import (
    KnowledgePoint,
    describe_verdict,
    mean_series,
    plot_dbn_counts,
    speed_problem,
)

__all__ = [
    "ResultsConfig",
    "TaskResult",
    "build_results",
    "clearly_above",
    "other_pages",
    "render_page",
    "run_command",
    "run_dir_name",
    "run_seeds",
    "task_result",
    "world_tasks",
]

PROTOCOL: dict[str, Any] = {"world": "core", "steps": 250_000, "seeds": 5, "trials": 100}
"""The protocol core's targets are set for: core, 250,000 steps, 5 seeds, the sync loop, 100
trials per checkpoint (each world's: :class:`.reference_values.WorldTargets`)."""

Echo = Callable[[str], None]


@dataclass
class ResultsConfig:
    """The options of ``scripts/learning_results.py``."""

    world: str = "core"
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3, 4, 5])
    steps: int = 250_000
    trials: int = 100
    every: int | None = 10_000
    at: list[int] = field(default_factory=list)
    """Steps evaluated besides the multiples of ``every`` (e.g. 20,000, the end of babbling, and
    the last three checkpoints that the targets compare with it)."""
    jobs: int = 2
    """Worker processes of each curve's evaluation."""
    run_jobs: int = 1
    """Runs at a time. One by default: two runs side by side on a 2-core machine share its
    cache and memory and each runs about 1.4× slower (docs/decisions.md 123), so only a run
    made alone measures the loop's own speed."""
    runs_dir: Path = Path("runs/results")
    out: Path = Path("docs")
    tasks: list[str] | None = None
    eval_seed: int = 0
    """Seed of the evaluation trials (``qlap curve --seed``)."""
    argv: list[str] = field(default_factory=list)
    """The command as typed, for the page."""


def run_dir_name(world: str, seed: int) -> str:
    """``W-sS``, the world spec made safe for a directory name (``core:floating`` →
    ``core_floating``)."""
    return f"{re.sub(r'[^A-Za-z0-9._-]', '_', world)}-s{seed}"


def run_command(world: str, steps: int, seed: int, out: Path) -> list[str]:
    """The ``qlap run`` command of one seed (without the interpreter)."""
    return ["qlap", "run", "--headless", "--placement", "sync", "--world", world,
            "--steps", str(steps), "--seed", str(seed), "--out", str(out), "--quiet"]


def world_tasks(world: str) -> list[str]:
    """The tasks of a world spec, in the world's order."""
    import worlds

    try:
        w = worlds.make(world)
    except (ValueError, ImportError, AttributeError, TypeError) as exc:
        raise AnalysisError(f"world {world!r}: {exc}") from None
    try:
        return list(w.tasks)
    finally:
        w.close()




AT_A_TIME = "# runs at a time: {n}"
"""The second line of a run's log (``RUNS/W-sS.log``): how many runs :func:`run_seeds` made
side by side, which the page's speed table shows (:func:`runs_at_a_time`)."""


def runs_at_a_time(run_dir: Path) -> int | None:
    """How many runs were made side by side with ``run_dir`` (its log's second line, written
    by :func:`run_seeds`); None when its log does not say (a run made otherwise)."""
    log = Path(run_dir).parent / f"{Path(run_dir).name}.log"
    try:
        with open(log, encoding="utf-8", errors="replace") as f:
            lines = [f.readline(), f.readline()]
    except OSError:
        return None
    prefix = AT_A_TIME.split("{n}")[0]
    n = lines[1].strip().removeprefix(prefix)
    return int(n) if lines[1].startswith(prefix) and n.isdigit() else None


def run_seeds(world: str, seeds: Sequence[int], steps: int, runs_dir: Path, jobs: int,
              echo: Echo = print, python: str = sys.executable) -> list[Path]:
    """Run every seed whose ``RUNS/W-sS/summary.json`` is missing, ``jobs`` at a time, each as
    ``qlap run --headless --placement sync … --quiet`` in its own process (its output in
    ``RUNS/W-sS.log``). Prints a line per finished run. Returns the run directories of all
    seeds; raises :class:`AnalysisError` when a run failed (the others are finished first)."""
    runs_dir = Path(runs_dir)
    dirs = {s: runs_dir / run_dir_name(world, s) for s in seeds}
    todo = [s for s in seeds if read_summary(dirs[s]) is None]
    at_a_time = max(1, min(jobs, len(todo)))
    echo(f"runs: {len(seeds) - len(todo)} of {len(seeds)} already done in {runs_dir}"
         + (f"; {len(todo)} to run, {at_a_time} at a time" if todo else ""))
    if not todo:
        return [dirs[s] for s in seeds]
    runs_dir.mkdir(parents=True, exist_ok=True)

    def one(seed: int) -> tuple[int, float]:
        cmd = run_command(world, steps, seed, dirs[seed])
        log = runs_dir / f"{dirs[seed].name}.log"
        t0 = time.perf_counter()
        with open(log, "w") as f:
            f.write(shlex.join(cmd) + "\n" + AT_A_TIME.format(n=at_a_time) + "\n")
            f.flush()
            rc = subprocess.run([python, "-m", "qlap_runtime.cli", *cmd[1:]], stdout=f,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL).returncode
        return rc, time.perf_counter() - t0

    failed = []
    with ThreadPoolExecutor(max_workers=at_a_time) as pool:
        futures = {pool.submit(one, s): s for s in todo}
        for i, fut in enumerate(as_completed(futures), 1):
            seed = futures[fut]
            name = dirs[seed].name
            rc, seconds = fut.result()
            summary = read_summary(dirs[seed])
            if rc != 0 or summary is None:
                failed.append(seed)
                echo(f"[{i}/{len(todo)}] {name}: FAILED (exit {rc}) after {seconds:.0f} s; "
                     f"see {runs_dir / (name + '.log')}")
                continue
            echo(f"[{i}/{len(todo)}] {name}: {summary.get('steps', steps):,} steps in "
                 f"{seconds:.0f} s ({summary.get('steps_per_s')} steps/s in the loop), "
                 f"k = {summary.get('k')}, {summary.get('dbns')} DBNs, "
                 f"{summary.get('plans')} plans, {summary.get('landmarks')} landmarks")
    if failed:
        raise AnalysisError(f"the runs of seed(s) {', '.join(map(str, failed))} failed")
    return [dirs[s] for s in seeds]


@dataclass(frozen=True)
class TaskResult:
    """One task's curve over the seeds, and what the page says of it."""

    task: str
    world: str
    points: list[CurvePoint]
    """The mean across seeds at every evaluated step."""
    baseline: CurveRow | None
    """The random policy on the same world, task, trials and trial seed."""
    labels: list[str]
    """The runs (seeds)."""
    trials: int


def task_result(run_dirs: Sequence[Path], task: str, curve_dir: Path, trials: int,
                every: int | None, eval_seed: int = 0, at: Sequence[int] = ()) -> TaskResult:
    """The curve of ``task`` over ``run_dirs`` as ``qlap curve … --out curve_dir`` left it in
    ``curve.csv``: the checkpoints ``--every`` selects, their mean and standard error across
    runs (:func:`.curve.aggregate`), and the random policy's row."""
    labels = run_labels(list(run_dirs))
    checkpoints = [c for d, label in zip(run_dirs, labels, strict=True)
                   for c in find_checkpoints(d, label)]
    world = run_world(run_dirs[0], find_checkpoints(run_dirs[0], labels[0]), None)
    wanted = {(c.run, c.step) for c in select_every(checkpoints, every, at)}
    rows = [r for r in read_rows(Path(curve_dir) / "curve.csv")
            if (r.task, r.world, r.trials, r.seed) == (task, world, trials, eval_seed)]
    ours = [r for r in rows if r.policy == "qlap" and (r.run, r.step) in wanted]
    baseline = next((r for r in rows if r.policy == "random" and r.run == RANDOM_RUN), None)
    return TaskResult(task, world, aggregate(ours, len(labels)), baseline, labels, trials)


# ---------------------------------------------------------------------------------------------
# Judging
# ---------------------------------------------------------------------------------------------
def _mark(ok: bool | None) -> str:
    return {True: "✅ pass", False: "❌ fail", None: "— n/a"}[ok]


def _world_base(world: str) -> str:
    return world.split(":", 1)[0]


def task_targets(res: TaskResult,
                 targets: ref.WorldTargets | None = None) -> list[tuple[str, str, bool | None]]:
    """(target, measured, met) of one task, by the targets of its world
    (:func:`.reference_values.targets_for`): the final reward (core tasks only), the margin
    over the random policy (core) or the final mean clearly above it (pong), the last three
    checkpoints above the 20,000-step one."""
    T = targets or ref.targets_for(res.world)
    pts = res.points
    end = pts[-1] if pts else None
    out: list[tuple[str, str, bool | None]] = []
    goal = T.task_reward.get(res.task) if _world_base(res.world) == T.world else None
    if goal is not None:
        out.append((f"mean reward at the end ≥ {goal:g}",
                    "—" if end is None else f"{end.mean_reward:.2f}",
                    None if end is None else end.mean_reward >= goal))
    base = res.baseline
    if T.above_random is not None:
        if end is not None and base is not None:
            margin = end.mean_reward - base.mean_reward
            out.append((f"at least {T.above_random:g} above the random policy",
                        f"{margin:+.2f} ({end.mean_reward:.2f} against {base.mean_reward:.2f})",
                        margin >= T.above_random))
        else:
            out.append((f"at least {T.above_random:g} above the random policy", "—", None))
    if T.clearly_above_random is not None:
        out.append(clearly_above(end, base, len(res.labels), T.clearly_above_random))
    at20 = next((p for p in pts if p.step == T.rise_from), None)
    last3 = pts[-3:]
    if at20 is None or len(last3) < 3 or any(p.step <= at20.step for p in last3):
        out.append(("each of the last three checkpoints above the 20k one",
                    "no 20k checkpoint, or fewer than three after it", None))
    else:
        out.append(("each of the last three checkpoints above the 20k one",
                    ", ".join(f"{p.mean_reward:.2f}" for p in last3)
                    + f" against {at20.mean_reward:.2f}",
                    all(p.mean_reward > at20.mean_reward for p in last3)))
    return out


def clearly_above(end: CurvePoint | None, base: CurveRow | None, n_runs: int,
                  z: float) -> tuple[str, str, bool | None]:
    """(target, measured, met) of "clearly above the random policy": the final mean over the
    seeds exceeds the random policy's mean by more than ``z`` standard errors of the
    difference, √(s.e.² across seeds + s.e.² of the random policy over its trials) (§7.3: the
    error bars are standard errors), and every seed's final mean exceeds the random policy's.
    n/a without a baseline, a final checkpoint, or at least two seeds there."""
    target = (f"clearly above the random policy: mean − random > {z:g} s.e. of the "
              "difference, and every seed above random")
    if end is None or base is None:
        return target, "—", None
    se = math.sqrt((0.0 if math.isnan(end.stderr) else end.stderr) ** 2 + base.stderr ** 2)
    margin = end.mean_reward - base.mean_reward
    seeds = list(end.runs.values())
    above = sum(x > base.mean_reward for x in seeds)
    measured = (f"{margin:+.2f} ({end.mean_reward:.2f} against {base.mean_reward:.2f}), "
                f"{z:g} s.e. = {z * se:.2f}; {above}/{n_runs} seeds above")
    if len(seeds) < 2 or math.isnan(end.stderr):
        return target, measured + " (fewer than two seeds: not judged)", None
    return target, measured, bool(margin > z * se and above == n_runs)


def _task_section(res: TaskResult, image: str | None,
                  targets: ref.WorldTargets = ref.CORE_TARGETS) -> list[str]:
    pts = res.points
    lines = [f"### {res.task}", ""]
    if not pts:
        return [*lines, "No evaluation in curve.csv.", ""]
    chosen: list[tuple[str, CurvePoint]] = []
    at20 = next((p for p in pts if p.step == targets.rise_from), None)
    if at20 is not None:
        chosen.append((f"{targets.rise_from // 1000}k (end of babbling)", at20))
    for p in pts[-3:]:
        if p is not at20:
            chosen.append((f"{p.step:,}" + (" (end)" if p is pts[-1] else ""), p))
    header = ["checkpoint", "mean reward ± s.e. across seeds", "success rate", "seeds",
              *res.labels]
    rows = []
    for name, p in chosen:
        rows.append([name, pm(p.mean_reward, p.stderr), f"{p.success_rate:.0%}",
                     str(len(p.runs)),
                     *(f"{p.runs[r]:.2f}" if r in p.runs else "—" for r in res.labels)])
    b = res.baseline
    if b is not None:
        rows.append(["random policy", f"{b.mean_reward:.2f} ± {b.stderr:.2f} (over trials)",
                     f"{b.success_rate:.0%}", "—", *("" for _ in res.labels)])
    lines += [table(header, rows), ""]
    lines += [table(["target", "measured", "met"],
                     [[t, m, _mark(ok)] for t, m, ok in task_targets(res, targets)]), ""]
    if image:
        lines += [f"![{res.task}: mean reward against steps]({image})", ""]
    return lines


def _knowledge_rows(data: Mapping[str, Any],
                    targets: ref.WorldTargets = ref.CORE_TARGETS) -> list[list[str]]:
    """The knowledge table: measure, reference, target, each seed, mean, seeds meeting it,
    mark (the mean against the target; "with a plan" asks every seed for one). ``targets``
    decide which rows are judged ("—" target: shown, not judged) and whether the core world's
    chapter-8 rows (Table 8.1, Fig. 7.9, u_x, rel(a)) are there; ``data["growth"]`` must have
    been judged by the same targets (:func:`.report.report_data`)."""
    T = targets
    runs = data["runs"]
    labels = list(runs)
    R = data["reference"]
    growth = data["growth"]
    n = len(labels)
    rows: list[list[str]] = []

    def add(measure: str, reference: str, target: str, cells: list[str], mean: str,
            per_run: list[bool | None], met: bool | None) -> None:
        judged = [x for x in per_run if x is not None]
        rows.append([measure, reference, target, *cells, mean,
                     f"{sum(judged)}/{n}" if judged else "—", _mark(met)])

    def mean_of(xs: Sequence[float | None]) -> float | None:
        ys = [float(x) for x in xs if x is not None]
        return sum(ys) / len(ys) if ys else None

    ks = [runs[r]["k"] for r in labels]
    mk = mean_of(ks)
    if T.k_range is None:
        add("window k (App. C)", f"≈ {R['k']['value']} (§7.10.1)", "—",
            [str(k) for k in ks], pm(mk, None, "{:.1f}"), [None] * n, None)
    else:
        k0, k1 = T.k_range
        add("window k (App. C)", f"≈ {R['k']['value']} (§7.10.1)", f"{k0} to {k1}",
            [str(k) for k in ks], pm(mk, None, "{:.1f}"),
            [None if k is None else k0 <= k <= k1 for k in ks],
            None if mk is None else k0 <= mk <= k1)
    limit = T.change_dbn_limit
    ch = [runs[r]["change_dbns"] for r in labels]
    mch = mean_of(ch)
    add("change DBNs at the end" + (" (Fig. 7.9)" if T.chapter_8 else ""),
        f"≈ {ref.CHANGE_DBNS}" if T.chapter_8 else "—",
        f"≤ {limit}", [str(c) for c in ch], pm(mch, None, "{:.1f}"),
        [c <= limit for c in ch], None if mch is None else mch <= limit)
    gm = data["growth_mean"]
    add(f"change DBNs not growing after {T.growth_after // 1000}k",
        "bounded (Fig. 7.9)" if T.chapter_8 else "—",
        f"fitted rise ≤ {T.growth_tolerance:.0%} of the mean",
        [_growth_cell(growth[r]) for r in labels], _growth_cell(gm),
        [growth[r]["flat"] for r in labels], gm["flat"])
    mag = [runs[r]["magnitude_dbns"] for r in labels]
    add("magnitude DBNs at the end", "—", "—", [str(m) for m in mag],
        pm(mean_of(mag), None, "{:.1f}"), [None] * n, None)
    med = [runs[r]["landmarks_median"] for r in labels]
    mmed = mean_of(med)
    gmed = T.landmarks_median
    add("landmarks per variable, median",
        f"{R['landmarks_median']:g} (Table 8.1)" if T.chapter_8 else "—",
        "—" if gmed is None else f"≤ {gmed:g}",
        ["—" if m is None else f"{m:g}" for m in med], pm(mmed, None, "{:.1f}"),
        [None if m is None or gmed is None else m <= gmed for m in med],
        None if mmed is None or gmed is None else mmed <= gmed)
    top = [runs[r]["landmarks_max"] for r in labels]
    mtop = mean_of(top)
    gmax = T.landmarks_max
    add("landmarks per variable, max",
        f"{R['landmarks_max']} (Table 8.1)" if T.chapter_8 else "—",
        "—" if gmax is None else f"≤ {gmax}",
        ["—" if t is None else f"{t} ({pretty(runs[r]['landmarks_max_variable'])})"
         for t, r in zip(top, labels, strict=True)], pm(mtop, None, "{:.1f}"),
        [None if t is None or gmax is None else t <= gmax for t in top],
        None if mtop is None or gmax is None else mtop <= gmax)
    nar = [runs[r]["narrow_count"] for r in labels]
    mnar = mean_of(nar)
    add("values narrower than the resolution", "none", "0", [str(x) for x in nar],
        pm(mnar, None, "{:.1f}"), [x == 0 for x in nar], None if mnar is None else mnar == 0)
    if not T.chapter_8:
        return rows
    lo, hi = ref.FRICTION_BAND
    (m0, m1), (p0, p1) = ref.U_X_LANDMARKS
    for side, band, reference in (("plus", f"[{lo:g}, {hi:g}]", f"[{p0}, {p1}]"),
                                  ("minus", f"[−{hi:g}, −{lo:g}]", f"[{m0}, {m1}]")):
        ux = [runs[r]["u_x"] for r in labels]
        ok = [None if u is None else len(u[side]) == 1 for u in ux]
        add(f"u_x landmarks centred in {band}", f"{reference} (Table 8.1)", "exactly one",
            ["n/a" if u is None else (", ".join(u[side]) or "none") for u in ux],
            f"{sum(1 for x in ok if x)}/{n} with one", ok,
            None if all(x is None for x in ok) else all(bool(x) for x in ok))
    for ra in T.actions:
        key = f"a({ra.variable}, {ra.value})"
        need_plan = ra.variable == "h_x.dot"
        acts = [runs[r]["actions"][key] for r in labels]
        mrel = mean_of([a["rel"] for a in acts])
        # an action the agent never called nor planned for does not meet the target
        per = [a["rel"] is not None and a["rel"] >= ra.target and (a["plan"] or not need_plan)
               for a in acts]
        met = (mrel is not None and all(a["rel"] is not None for a in acts)
               and mrel >= ra.target and (not need_plan or all(a["plan"] for a in acts)))
        add(f"rel {pretty(key)} ({ra.source})", f"{ra.rel:.2f}",
            f"≥ {ra.target:.2f}" + (" with a plan" if need_plan else ""),
            ["no such action" if a["rel"] is None else
             f"{a['rel']:.2f}" + (" (plan)" if a["plan"] else " (no plan)") for a in acts],
            pm(mrel, None) + f", plan {sum(a['plan'] for a in acts)}/{n}", per, met)
    return rows


def _landmark_rows(data: Mapping[str, Any]) -> list[str]:
    """Landmarks of each motor and magnitude variable (initial ones included), one column per
    seed and the largest: the figures behind the median and max rows."""
    runs = data["runs"]
    labels = list(runs)
    variables = list(dict.fromkeys(v for r in labels for v in runs[r]["landmarks"]))
    if not variables:
        return []
    rows = []
    for v in variables:
        counts = [runs[r]["landmarks"].get(v) for r in labels]
        have = [c for c in counts if c is not None]
        rows.append([pretty(v), *("—" if c is None else str(c) for c in counts),
                     str(max(have)) if have else "—"])
    out = ["Landmarks per variable (initial ones included):", "",
           table(["variable", *labels, "max"], rows), ""]
    narrow = [[r, pretty(x["variable"]), x["value"], f"{x['width']:.4g}", f"{x['limit']:.4g}",
               f"{x['width'] / x['limit']:.1%}"]
              for r in labels for x in runs[r]["narrow"] if x["limit"] > 0]
    if narrow:
        out += ["Values narrower than the resolution (the resolution of each seed's final "
                "checkpoint: the world's declared one, else for a magnitude half its §4.4.2 "
                "bin, measured on the history and fixed at the end of babbling):", "",
                table(["run", "variable", "value", "width", "resolution", "width / resolution"],
                       narrow), ""]
    return out


def _growth_cell(v: Mapping[str, Any]) -> str:
    if v.get("rise") is None:
        return "n/a (too short)"
    return f"{v['rise']:+.1f} of {v['allowed']:.1f} allowed"


def _speed_rows(data: Mapping[str, Any], together: Mapping[str, int | None]
                ) -> tuple[list[list[str]], float | None, int]:
    """The speed table's rows, the mean steps/s of the runs made alone (None: none was), and
    how many runs with a speed were not made alone (or do not say)."""
    rows = []
    values = []
    others = 0
    for label, sp in data["speed"].items():
        n = together.get(label)
        made = "—" if n is None else ("alone" if n == 1 else f"{n} at a time")
        if sp is None or sp.get("steps_per_s") is None:
            rows.append([label, "—", "—", speed_problem(sp), made])
            continue
        if n == 1:
            values.append(float(sp["steps_per_s"]))
        else:
            others += 1
        rows.append([label, f"{sp['steps_per_s']:,.1f}",
                     "—" if sp.get("wall_time_s") is None else f"{sp['wall_time_s']:,.0f}",
                     str(sp.get("placement", "sync")), made])
    mean = sum(values) / len(values) if values else None
    return rows, mean, others


def _publish(path: Path, data: bytes) -> None:
    """Write a page or image atomically, readable by all as a document should be (the
    temporary file behind an atomic write is private)."""
    atomic_write_bytes(path, data)
    os.chmod(path, 0o644)


def _git_commit(cwd: Path, outputs: Sequence[Path] = ()) -> str:
    """HEAD, "with uncommitted changes" when tracked files differ from it — except
    ``outputs``, the page and images this very run writes."""
    excluded = [f":(exclude){_shown(path)}" for path in outputs]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=cwd,
                              capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no",
                                "--", ".", *excluded],
                               cwd=cwd, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    if head.returncode != 0:
        return "unknown"
    return head.stdout.strip() + (" with uncommitted changes" if dirty.stdout.strip() else "")


def _shown(path: Path) -> str:
    """A path as the page shows it: relative to the working directory when it is below it."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def render_page(cfg: ResultsConfig, tasks: Sequence[TaskResult], data: Mapping[str, Any],
                images: Mapping[str, str], run_dirs: Sequence[Path], *,
                date: str | None = None, cores: int | None = None,
                commit: str | None = None,
                see_also: Sequence[tuple[str, str]] = ()) -> str:
    """The Markdown of the results page, judged by the targets of ``cfg.world``
    (:func:`.reference_values.targets_for`). ``images``: task name (and ``"dbn"``) → the
    image's path relative to the page; ``see_also``: (text, path relative to the page) of
    other results pages, listed under the introduction (``data`` from
    :func:`.report.report_data` with the same targets)."""
    T = ref.targets_for(cfg.world)
    core = T is ref.CORE_TARGETS
    date = date or _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    cores = cores if cores is not None else os.cpu_count()
    commit = commit or _git_commit(Path.cwd(), (Path(cfg.out) / "results.md",
                                                Path(cfg.out) / "results"))
    labels = list(data["runs"])
    n = len(labels)
    typed = shlex.join(cfg.argv) if cfg.argv else "scripts/learning_results.py"
    full = shlex.join([
        "scripts/learning_results.py", "--world", cfg.world, "--seeds",
        *map(str, cfg.seeds), "--steps", str(cfg.steps), "--trials", str(cfg.trials),
        "--every", str(cfg.every or 0), *(["--at", *map(str, cfg.at)] if cfg.at else []),
        "--jobs", str(cfg.jobs), "--run-jobs", str(cfg.run_jobs), "--runs-dir",
        _shown(cfg.runs_dir), "--out", _shown(cfg.out), "--tasks",
        *[t.task for t in tasks]])
    protocol_ok = (_world_base(cfg.world) == T.world and cfg.steps == T.steps
                   and len(cfg.seeds) >= T.seeds and cfg.trials == T.trials)
    L: list[str] = [
        "# Learning results" + ("" if core else f": {T.world}"),
        "",
        "What a QLAP agent learns in the synchronous loop, over several seeds: the task "
        + ("curves of §7.2, the knowledge of chapter 8 and the DBN count of Fig. 7.9 of "
           if core else
           "curve of §7.10 (evaluated as §7.2), the knowledge and the DBN count (as Fig. 7.9) "
           "of ")
        + "J. Mugan, "
        "*Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*, "
        "PhD dissertation, UT Austin, 2010, each beside the reference's figures and the targets "
        "this project set itself. Generated by `scripts/learning_results.py`; do not edit by "
        "hand.",
        "",
        f"- Generated {date} on a machine with {cores} cores (Python "
        f"{platform.python_version()}, {platform.system()}), commit {commit}.",
        f"- World `{cfg.world}`, seeds {', '.join(map(str, cfg.seeds))}, {cfg.steps:,} steps "
        f"each, made {cfg.run_jobs} at a time (`--run-jobs`), `--jobs {cfg.jobs}` evaluations "
        "at a time; checkpoints evaluated "
        + ("all" if not cfg.every else f"every {cfg.every:,} steps and the last")
        + f", {cfg.trials} trials each (trial seed {cfg.eval_seed}, the same set-ups for every "
        "checkpoint), learning off (plans' Sarsa adapts within a trial and is undone before "
        "the next, docs/decisions.md 37), as `qlap eval`.",
        *(f"- See also: {text}, [{path}]({path})." for text, path in see_also),
        "",
        "The command (as typed, then with every option spelled out):",
        "",
        "```sh",
        typed,
        full,
        "```",
        "",
        "Each seed was run as",
        "",
        "```sh",
        shlex.join(run_command(cfg.world, cfg.steps, cfg.seeds[0],
                               Path(_shown(cfg.runs_dir)) / run_dir_name(cfg.world,
                                                                         cfg.seeds[0]))),
        "```",
        "",
        "then `qlap curve RUN_DIRS --task T --trials N --every E [--at STEP ...] "
        "--out RUNS/curve-T` and `qlap report --json RUN_DIRS` (docs/analysis.md).",
        "",
    ]
    if not protocol_ok:
        L += ["> **Not the targets' protocol.** The targets below are set for the "
              + ("core world" if core else T.world) + ", "
              f"{T.steps:,} steps, at least {T.seeds} seeds and "
              f"{T.trials} trials a checkpoint; this page ran {cfg.world}, "
              f"{cfg.steps:,} steps, {len(cfg.seeds)} seed(s), {cfg.trials} trials. The marks "
              "are indicative only.", ""]

    krows = _knowledge_rows(data, T)
    srows, smean, shared = _speed_rows(
        data, {Path(d).name: runs_at_a_time(Path(d)) for d in run_dirs})
    glance = [[t.task, target, measured, _mark(ok)]
              for t in tasks for target, measured, ok in task_targets(t, T)]
    glance += [["knowledge", f"{r[0]}: {r[2]}", r[-3], r[-1]] for r in krows if r[2] != "—"]
    if T.steps_per_s is not None:
        glance.append(["speed", f"sync loop ≥ {T.steps_per_s:,.0f} steps/s (mean of the runs "
                       "made alone)",
                       "—" if smean is None else f"{smean:,.1f}",
                       _mark(None if smean is None else smean >= T.steps_per_s)])
    met = sum(row[-1] == _mark(True) for row in glance)
    judged = sum(row[-1] != _mark(None) for row in glance)
    L += ["## Targets at a glance", "",
          f"{met} of {judged} judged targets met (means over the seeds; details below).", "",
          table(["what", "target", "measured", "met"], glance), ""]

    L += ["## Tasks", "",
          f"Mean reward per trial ({T.reward}) "
          f"at the end of babbling ({T.rise_from // 1000}k), at the last three evaluated "
          "checkpoints and at the "
          "end, as the mean over the seeds ± its standard error across seeds (§7.3: \"all "
          "error bars are standard error\"); the success rate is the mean over the seeds. The "
          "random policy is evaluated once on the same world, task, trials and trial seed: it "
          "meets the agent's set-ups (docs/decisions.md 112).",
          "", T.note, ""]
    for t in tasks:
        L += _task_section(t, images.get(t.task), T)

    L += ["## Knowledge at the end", "",
          "From each seed's `knowledge.json`, beside the reference's figures (Tables 8.1–8.5, "
          "Fig. 7.9, App. C)"
          + ("" if T.chapter_8 else
             ", of which only k applies to this world (§7.10.1); the core world's chapter-8 rows "
             "(u_x at the friction threshold, rel(a) of Tables 8.2–8.5) are left out, and a "
             "measure whose target is — is shown, not judged")
          + ". *Seeds* counts the seeds meeting the target; the mark judges "
          "the mean over the seeds (and, where a plan is asked for, every seed having one). "
          "Landmarks are counted per motor and magnitude variable, the initial ones included "
          "as in Table 8.1; a value is narrower than the resolution when a landmark range or "
          "the open interval between two consecutive landmarks is narrower than the "
          "variable's resolution.", "",
          table(["measure", "reference", "target", *labels, "mean", "seeds", "met"],
                 krows), ""]
    if not T.chapter_8:
        L += _landmark_rows(data)

    L += ["## DBNs over time", "",
          "Change DBNs at every checkpoint of each seed (grey) and their mean ± s.e. across "
          + (f"seeds, as Fig. 7.9 (where the reference's count stays about {ref.CHANGE_DBNS}, "
             "dropping when the hand's actions become reliable and again when DBNs that became "
             "no plan are deleted at age 100,000)." if T.chapter_8 else
             "seeds, drawn as Fig. 7.9 draws the core world's (the reference gives no count "
             "for this world)."), ""]
    if images.get("dbn"):
        L += [f"![change DBNs against steps]({images['dbn']})", ""]
    timelines = {label: [KnowledgePoint(**q) for q in pts]
                 for label, pts in data["timeline"].items()}
    series = {f: {p.step: p for p in mean_series(timelines, f)}
              for f in ("change_dbns", "magnitude_dbns", "plans", "landmarks")}
    steps = sorted(series["change_dbns"])
    if steps:
        shown = [s for s in steps
                 if s == T.rise_from or s % T.timeline_every == 0 or s == steps[-1]]
        rows = [[f"{s:,}", str(series['change_dbns'][s].n),
                 *(pm(series[f][s].mean, series[f][s].stderr, "{:.1f}")
                   for f in ("change_dbns", "magnitude_dbns", "plans", "landmarks"))]
                for s in shown]
        L += [table(["step", "seeds", "change DBNs", "magnitude DBNs", "plans", "landmarks"],
                     rows), ""]
    L += [f"Verdict, **change DBNs ≤ {T.change_dbn_limit} and not growing after "
          f"{T.growth_after:,} steps**: bounded means at most {T.change_dbn_limit} change "
          "DBNs at the last checkpoint; not growing means that the least-squares line through "
          f"the counts of the checkpoints from step {T.growth_after:,} on rises, from the "
          f"first of them to the last, by at most {T.growth_tolerance:.0%} of their mean "
          "count (a fitted line, so that one checkpoint just before or after a wave of "
          "deletions does not decide alone). The mean is judged on the steps every seed has.",
          ""]
    L += [table(["run", "verdict"],
                 [[label, describe_verdict(data["growth"][label])] for label in labels]
                 + ([["mean", describe_verdict(data["growth_mean"])]] if n > 1 else [])), ""]

    L += ["## Speed of the synchronous loop", "",
          "Agent steps per second of each run's loop as the run recorded it (`summary.json` "
          f"`steps_per_s`); the runs this command makes run {cfg.run_jobs} at a time "
          f"(`--run-jobs`) on {cores} cores, and a finished run already in the runs directory "
          "is reused as it is (its log says how many ran beside it). Only the runs made alone "
          "are judged: two runs side by side on a 2-core machine share its cache and memory "
          "and each runs about 1.4× slower (docs/decisions.md 123). "
          + (f"Target: a mean of at least {T.steps_per_s:,.0f} steps/s over a 250,000-step "
             "core run (a benchmark, not a test)." if T.steps_per_s is not None else
             f"No target for this world (the {ref.SYNC_STEPS_PER_S:,.0f} steps/s target is "
             "set for a 250,000-step core run)."), "",
          table(["run", "steps/s", "wall time (s)", "placement", "made"],
                 [*srows, ["mean of the runs made alone",
                           "—" if smean is None else f"{smean:,.1f}", "", "", ""]]),
          "",
          f"Mean of the runs made alone {'—' if smean is None else f'{smean:,.1f}'} steps/s"
          + (": " + _mark(None if smean is None else smean >= T.steps_per_s)
             + f" (target ≥ {T.steps_per_s:,.0f})" if T.steps_per_s is not None else
             " (not judged)")
          + (f"; {shared} run(s) made beside others are shown, not judged." if shared
             else "."), ""]
    L += ["## Files", "",
          f"Runs: `{_shown(cfg.runs_dir)}/` ({', '.join(Path(d).name for d in run_dirs)}); "
          f"curves: `{_shown(cfg.runs_dir)}/curve-TASK/curve.csv` (docs/analysis.md); the "
          f"knowledge figures: `{_shown(cfg.runs_dir)}/report.json` (`qlap report --json`).",
          ""]
    return "\n".join(L)


def other_pages(out: Path, targets: ref.WorldTargets) -> list[tuple[str, str]]:
    """The pages core's page links: each other world's ``OUT/W/results.md`` that exists
    (``--out docs/pong`` beside ``--out docs``). Other worlds' pages link none."""
    if targets is not ref.CORE_TARGETS:
        return []
    return [(f"the same page for {t.world} ({t.steps:,}-step runs, at least {t.seeds} seeds)",
             f"{t.world}/results.md")
            for t in ref.WORLD_TARGETS.values()
            if t is not ref.CORE_TARGETS and (Path(out) / t.world / "results.md").is_file()]


def build_results(cfg: ResultsConfig, echo: Echo = print) -> int:
    """Run the missing seeds, the curves, the report; write ``OUT/results.md`` and
    ``OUT/results/*.png``. Returns 0, or 1 when an evaluation failed (the page is written
    with what there is). Raises :class:`AnalysisError` for unusable options or failed runs."""
    tasks = cfg.tasks or world_tasks(cfg.world)
    known = world_tasks(cfg.world)
    unknown = [t for t in tasks if t not in known]
    if unknown:
        from worlds.evaluate import no_task

        raise AnalysisError(no_task(cfg.world, unknown[0], known))
    if not cfg.seeds:
        raise AnalysisError("give at least one seed")
    if len(set(cfg.seeds)) != len(cfg.seeds):
        raise AnalysisError("a seed is given twice")
    t0 = time.perf_counter()
    run_dirs = run_seeds(cfg.world, cfg.seeds, cfg.steps, cfg.runs_dir, cfg.run_jobs, echo)

    failures = 0
    results = []
    for task in tasks:
        curve_dir = Path(cfg.runs_dir) / f"curve-{task}"
        echo(f"\ncurve of {task} over {len(run_dirs)} seed(s) -> {curve_dir}")
        failures += main_curve(run_dirs, task, cfg.trials, cfg.jobs, cfg.eval_seed, curve_dir,
                               cfg.world, echo=echo, every=cfg.every or None, at=cfg.at)
        results.append(task_result(run_dirs, task, curve_dir, cfg.trials, cfg.every or None,
                                   cfg.eval_seed, cfg.at))

    echo("\nknowledge (qlap report --json)")
    targets = ref.targets_for(cfg.world)
    data = report_data(run_dirs, targets)
    atomic_write_bytes(Path(cfg.runs_dir) / "report.json",
                       json.dumps(data, indent=1, ensure_ascii=False).encode())

    out = Path(cfg.out)
    img_dir = out / "results"
    images: dict[str, str] = {}
    for res in results:
        src = Path(cfg.runs_dir) / f"curve-{res.task}" / "curve.png"
        if src.is_file():
            name = f"curve-{res.task}.png"
            _publish(img_dir / name, src.read_bytes())
            images[res.task] = f"results/{name}"
    timelines = {label: [KnowledgePoint(**q) for q in pts]
                 for label, pts in data["timeline"].items()}
    try:
        plot_dbn_counts(timelines, img_dir / "dbn-count.png",
                        f"change DBNs on {cfg.world}: {len(timelines)} seed(s)",
                        targets=targets)
        os.chmod(img_dir / "dbn-count.png", 0o644)
        images["dbn"] = "results/dbn-count.png"
    except ImportError:
        echo("matplotlib is missing (pip install -e .[experiments]): no DBN figure")
    page = render_page(cfg, results, data, images, run_dirs,
                       see_also=other_pages(out, targets))
    _publish(out / "results.md", page.encode())
    echo(f"\nwrote {out / 'results.md'} and {len(images)} image(s) in {img_dir} "
         f"({time.perf_counter() - t0:.0f} s)")
    if failures:
        echo(f"{failures} curve(s) had failed evaluations: see the lines marked FAILED")
    return 1 if failures else 0
