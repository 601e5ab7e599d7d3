"""``RESULTS.md`` of an experiment: figures, tables, tests beside the reference's, the command.

After a sweep (:mod:`.engine`), everything recorded for its runs is gathered: each arm's agents'
evaluations by task (the curves of §7.2, drawn at step − the arm's offset), the averages after
the excluded start with their F tests (§7.3, :mod:`.stats`) beside those of the reference's
captions and Tables 7.2 and 7.4, the change DBNs and calls over time where the experiment asks
for them (:mod:`.knowledge`). Written atomically into the experiment's directory:
``RESULTS.md``, one ``TASK.png`` per task, ``dbn-count.png``, ``calls-N.png``, ``curves.csv``
(mean and s.e. per arm, task and step), ``agents.csv`` (every agent's value), ``tests.csv`` (the
F tests) and ``experiment.json`` (the configured experiment). The reference is J. Mugan,
*Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD
dissertation, UT Austin, 2010.
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import math
import os
import platform
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..analysis.curve import RANDOM_RUN
from ..analysis.markdown import num, pm, table
from ..analysis.runs import read_summary
from ..qlap.checkpoint import atomic_write_bytes
from . import stats
from .engine import SweepResult
from .figures import PanelData, plot_series, plot_task
from .knowledge import call_series, dbn_series
from .spec import Experiment
from .sweep import Sweep

__all__ = ["Results", "TestRow", "collect", "write_report"]

PENDING = ("**Provisional.** The QLAP agent's learning is still being brought to the "
           "reference's fidelity; these figures measure the agent as it is at the commit "
           "below and will be regenerated with the same command.")


@dataclass(frozen=True)
class TestRow:
    """One F test: measured, and the reference's when it gives one."""

    task: str
    panel: str
    arm: str
    versus: str
    measured: stats.AnovaResult | None
    means: tuple[float, float]
    reference: str
    source: str


@dataclass
class Results:
    """What a sweep measured, ready for tables and figures."""

    sweep: Sweep
    series: dict[tuple[str, str], dict[str, dict[int, float]]] = field(default_factory=dict)
    """(arm, task) → {agent run: {drawn step: mean reward}}."""
    random: dict[tuple[str, str], float] = field(default_factory=dict)
    """(eval world, task) → the random policy's mean reward."""
    tests: list[TestRow] = field(default_factory=list)
    time_effects: dict[tuple[str, str], stats.AnovaResult | None] = field(default_factory=dict)
    dbns: dict[str, dict[str, dict[int, float]]] = field(default_factory=dict)
    """arm → {agent run: {drawn step: change DBNs}}."""
    calls: dict[str, dict[str, dict[str, dict[int, float]]]] = field(default_factory=dict)
    """action set → arm → {agent run: {drawn step: calls}}."""


def collect(sweep: Sweep) -> Results:
    """Gather the evaluations (and knowledge counts) recorded for ``sweep``'s runs."""
    exp = sweep.experiment
    res = Results(sweep)
    rows = sweep.rows()
    for r in rows.values():
        if r.policy == "random" and r.run == RANDOM_RUN and r.trials == exp.trials:
            res.random[(r.world, r.task)] = r.mean_reward
    index = {(r.run, r.step, r.world, r.task, r.trials, r.seed): r for r in rows.values()
             if r.run != RANDOM_RUN}
    for label, ar in sweep.arms.items():
        for task in exp.tasks:
            series: dict[str, dict[int, float]] = {}
            for run in ar.runs:
                pts = {}
                for s in ar.steps:
                    row = index.get((run, s, ar.eval_world, task, exp.trials, 0))
                    if row is not None:
                        pts[s - ar.offset] = row.mean_reward
                series[run] = pts
            res.series[(label, task)] = series
    after = exp.anova_from()
    refs = {(r.task, r.arm, r.versus): r for r in exp.reference}
    for task in exp.tasks:
        seen = set()
        for panel in exp.panels:
            for arm, versus in panel.tests:
                if (arm, versus) in seen:
                    continue
                seen.add((arm, versus))
                a = stats.window_means(res.series[(arm, task)], after)
                b = stats.window_means(res.series[(versus, task)], after)
                test = stats.between_anova({arm: list(a.values()), versus: list(b.values())}) \
                    if a and b else None
                ref = refs.get((task, arm, versus))
                res.tests.append(TestRow(
                    task, panel.key, arm, versus, test,
                    (stats.mean_se(a.values())[0], stats.mean_se(b.values())[0]),
                    stats.format_f(ref.F, ref.sig) if ref else "—", ref.source if ref else ""))
        for label in sweep.arms:
            res.time_effects[(label, task)] = stats.time_anova(res.series[(label, task)],
                                                               after)
    if "dbn_count" in exp.figures or "calls" in exp.figures:
        for label, ar in sweep.arms.items():
            for run in ar.runs:
                run_dir = sweep.run_dir(run)
                if not (run_dir / "checkpoints").is_dir():
                    continue
                if "dbn_count" in exp.figures and ar.arm.condition.kind == "qlap":
                    res.dbns.setdefault(label, {})[run] = {
                        s - ar.offset: v for s, v in dbn_series(run_dir).items()}
                if "calls" in exp.figures and ar.arm.condition.kind == "qlap":
                    for name, pts in call_series(run_dir).items():
                        res.calls.setdefault(name, {}).setdefault(label, {})[run] = {
                            s - ar.offset: v for s, v in pts.items()}
    return res


F3 = "{:.3f}"
"""The reports' figures: three decimals."""


# ---------------------------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------------------------
def _csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


def _git() -> str:
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True,
                             text=True, cwd=Path(__file__).resolve().parents[2], timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


def _final(series: dict[str, dict[int, float]]) -> tuple[float, float, int]:
    pts = stats.curve(series)
    return (pts[-1].mean, pts[-1].stderr, pts[-1].n) if pts else (math.nan, math.nan, 0)


def _mean_points(per_agent: dict[str, dict[int, float]]) -> list[stats.Point]:
    return stats.curve(per_agent)


def write_report(sweep: Sweep, command: str, spelled: str,
                 result: SweepResult | None = None) -> Path:
    """Write the experiment's tables, figures and RESULTS.md; returns RESULTS.md's path."""
    exp = sweep.experiment
    out = sweep.out
    out.mkdir(parents=True, exist_ok=True)
    res = collect(sweep)
    after = exp.anova_from()
    arm_order = list(sweep.arms)
    atomic_write_bytes(out / "experiment.json",
                       json.dumps(exp.to_json(), indent=1, ensure_ascii=False).encode())

    curve_rows, agent_rows = [], []
    for (arm, task), series in res.series.items():
        for p in stats.curve(series):
            curve_rows.append([arm, task, p.step, p.n, p.mean, p.stderr])
        for run, pts in series.items():
            for s, v in sorted(pts.items()):
                agent_rows.append([arm, task, run, s, v])
    _csv(out / "curves.csv", ["arm", "task", "step", "agents", "mean_reward", "stderr"],
         curve_rows)
    _csv(out / "agents.csv", ["arm", "task", "run", "step", "mean_reward"], agent_rows)
    _csv(out / "tests.csv",
         ["task", "panel", "arm", "versus", "F", "df1", "df2", "sig", "n_arm", "n_versus",
          "mean_arm", "mean_versus", "reference", "source"],
         [[t.task, t.panel, t.arm, t.versus,
           *(["", "", "", "", "", ""] if t.measured is None else
             [t.measured.F, t.measured.df1, t.measured.df2, t.measured.sig,
              *t.measured.n]), t.means[0], t.means[1], t.reference, t.source]
          for t in res.tests])

    figures: list[str] = []
    for task in exp.tasks:
        panels = []
        for panel in exp.panels:
            curves = {a: stats.curve(res.series[(a, task)]) for a in panel.arms}
            bars = {a: stats.mean_se(stats.window_means(res.series[(a, task)],
                                                        after).values())
                    for a in panel.arms}
            captions = [f"{t.arm} vs {t.versus}: "
                        f"{t.measured.caption() if t.measured else '—'}"
                        + (f" (ref. {t.reference})" if t.reference != "—" else "")
                        for t in res.tests if t.task == task and t.panel == panel.key]
            panels.append(PanelData(panel.key, panel.title, curves, bars, captions))
        world0 = sweep.arms[exp.arms[0].label].eval_world
        try:
            plot_task(task, panels, res.random.get((world0, task)), after,
                      out / f"{task}.png", f"{exp.section} {exp.title}: {task}", arm_order)
            figures.append(f"{task}.png")
        except ImportError:
            pass
    if res.dbns:
        plot_series({a: _mean_points(v) for a, v in res.dbns.items()}, out / "dbn-count.png",
                    "Change DBNs over time (Figs. 7.9, 7.24)", "change DBNs", 250.0,
                    "reference ≈ 250 (Fig. 7.9)")
    if res.calls:
        for i, (name, arms) in enumerate(res.calls.items()):
            plot_series({a: _mean_points(v) for a, v in arms.items()}, out / f"calls-{i + 1}.png",
                        f"Cumulative calls: {name}", "calls")

    text = _page(exp, sweep, res, command, spelled, result, after)
    atomic_write_bytes(out / "RESULTS.md", text.encode())
    return out / "RESULTS.md"


def _page(exp: Experiment, sweep: Sweep, res: Results, command: str, spelled: str,
          result: SweepResult | None, after: int) -> str:
    lines = [f"# {exp.name}: {exp.title} ({exp.section})", ""]
    if exp.quick_mode:
        lines += ["> **Quick preset** (`--quick`): a smoke run of the machinery, not a "
                  "measurement — too few agents, steps and trials to say anything.", ""]
    lines += [f"> {PENDING}", "",
              f"**The reference's claim** ({exp.section}, {exp.figure_refs}): {exp.claim}", "",
              "Regenerate with exactly:", "", "```sh", command, "```", "",
              "which is, with every option spelled out:", "", "```sh", spelled, "```", ""]
    proto = dict(exp.reference_protocol)
    lines += [table(["setting", "here", "reference"], [
        ["agents per condition", str(exp.agents), proto.get("agents", "20 (§7.3)")],
        ["steps of learning", f"{exp.steps:,}", proto.get("steps", "250,000 (§7.2)")],
        ["trials per evaluation", str(exp.trials), "100 (§7.2.1)"],
        ["checkpoints evaluated", f"every {exp.eval_every:,} steps", "every 10,000 steps"],
        ["bars and F tests", f"checkpoints after step {after:,}" if after else "every checkpoint",
         "after 100,000 steps (§7.3)" if exp.exclude_fraction else "all 150,000 steps (§7.5.3)"],
    ]), ""]
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines += [f"Written {stamp} on {os.cpu_count()} cores, Python {platform.python_version()}, "
              f"commit {_git()}.", ""]
    if result is not None:
        sps = result.steps_run / result.agent_seconds if result.agent_seconds else None
        lines += [f"This invocation: {result.runs_done} agent runs finished "
                  f"({result.runs_reused} reused), {result.evals_done} evaluations "
                  f"({result.evals_reused} reused) in {result.wall_s:.0f} s"
                  + (f"; {sps:,.0f} agent steps/s per worker" if sps else "") + ".", ""]

    conds = table(["condition", "world", "learner", "runs"], [
        [label, ar.arm.world_spec(exp.steps), ar.arm.condition.description or
         ar.arm.condition.kind, str(len(ar.runs))] for label, ar in sweep.arms.items()])
    lines += ["## Conditions", "", conds, ""]

    for task in exp.tasks:
        lines += [f"## {task}", ""]
        if (sweep.out / f"{task}.png").exists():
            lines += [f"![{task}]({task}.png)", ""]
        rows = []
        for label, ar in sweep.arms.items():
            series = res.series[(label, task)]
            bar = stats.mean_se(stats.window_means(series, after).values())
            end = _final(series)
            rnd = res.random.get((ar.eval_world, task))
            rows.append([label, pm(bar[0], bar[1], F3), str(bar[2]), pm(end[0], end[1], F3),
                         num(rnd, F3)])
        lines += [table(["condition", f"mean after {after:,} ± s.e." if after else
                          "mean over all ± s.e.", "agents", "at the last checkpoint",
                          "random policy"], rows), ""]
        tests = [t for t in res.tests if t.task == task]
        if tests:
            lines += [table(["test", "reference", "measured", "means (arm, versus)"], [
                [f"{t.arm} vs {t.versus}",
                 f"{t.reference} ({t.source})" if t.source else t.reference,
                 (t.measured.caption() + f" (df {t.measured.df1:g}, {t.measured.df2:g})")
                 if t.measured else "— (too few agents or no variance)",
                 f"{num(t.means[0], F3)}, {num(t.means[1], F3)}"] for t in tests]), ""]
        effects = [(label, res.time_effects.get((label, task))) for label in sweep.arms]
        if any(e is not None for _, e in effects):
            lines += ["Change over the checkpoints within each condition (repeated-measures "
                      "ANOVA, statsmodels AnovaRM, the checkpoint as the within-subject "
                      "factor): " + "; ".join(f"{label} {e.caption()}" for label, e in effects
                                              if e is not None) + ".", ""]
        for p in exp.panels:
            if p.expect:
                lines.append(f"- Reference, ({p.key}) {p.title}: {p.expect}.")
        lines.append("")

    if res.dbns:
        lines += ["## Change DBNs over time (Figs. 7.9, 7.24)", "",
                  "![change DBNs](dbn-count.png)", ""]
        rows = []
        for label, per in res.dbns.items():
            pts = stats.curve(per)
            peak = max((p.mean for p in pts), default=math.nan)
            rows.append([label, pm(pts[-1].mean, pts[-1].stderr, F3) if pts else "—",
                         num(peak, "{:.1f}"), str(len(per))])
        lines += [table(["condition", "change DBNs at the end ± s.e.", "peak of the mean",
                          "agents"], rows), "",
                  "Reference: about 250 change DBNs in the core world, bounded, with two "
                  "drops (Fig. 7.9); relevant variables increase the count, irrelevant ones do "
                  "not (§7.6.3); no IAC, NRC and all targeted use more DBNs (Figs. 7.24, "
                  "7.25).", ""]
    if res.calls:
        lines += ["## Cumulative calls to sets of actions (Figs. 7.21–7.23)", ""]
        lines += [f"![{name}](calls-{i + 1}.png)" for i, name in enumerate(res.calls)] + [""]
        arms = list(dict.fromkeys(a for by_arm in res.calls.values() for a in by_arm))
        rows = []
        for a in arms:
            cells = []
            for by_arm in res.calls.values():
                last = stats.curve(by_arm.get(a, {}))
                cells.append(pm(last[-1].mean, last[-1].stderr, F3) if last else "—")
            rows.append([a, *cells])
        lines += [table(["condition", *(f"calls at the end: {n}" for n in res.calls)], rows),
                  "", "Calls count every finished call of an action (practice and as a step "
                  "of a plan), an upper bound of the reference's exploratory calls.", ""]

    if exp.notes:
        lines += ["## What the reference reports", ""] + [f"- {n}" for n in exp.notes] + [""]
    lines += ["## Runs", "", f"Agent runs are in `{sweep.root / 'agents'}` (shared by every "
              "experiment that needs the same run); their evaluations in each run's "
              "`curve.csv`.", ""]
    rows = []
    for label, ar in sweep.arms.items():
        for run in ar.runs:
            spec = sweep.runs[run]
            for what, key in (("", run), ("landmarks from ", spec.landmark_run)):
                if key is None:
                    continue
                summary = read_summary(sweep.run_dir(key))
                rows.append([label, str(spec.seed), f"{what}`{key}`",
                             str(summary.get("steps_per_s", "—")) if summary else "not run"])
    lines += [table(["condition", "seed", "run", "steps/s"], rows), ""]
    if result is not None and result.failures:
        lines += ["## Failures", ""] + [f"- {f}" for f in result.failures] + [""]
    lines += ["Tables: `curves.csv` (mean and s.e. per condition, task and step), "
              "`agents.csv` (each agent), `tests.csv` (the F tests), `experiment.json` "
              "(the experiment as run). How they are computed: docs/experiments.md.", ""]
    return "\n".join(lines)


