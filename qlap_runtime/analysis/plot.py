"""``qlap plot``: a run's metrics log (and its learning curve) drawn as ``RUN_DIR/metrics.png``.

The metrics log (``metrics.jsonl``, docs/outputs.md) has a line every 1,000 steps; the figure
shows what the agent knows over time (change and magnitude DBNs, plans, landmarks, sufficiently
reliable actions), what exploration chose (IAC practice choices and babbling commands per
interval, the practice success rate), the speed (steps/s), and, when the run has a
``curve.csv`` (``qlap curve``, docs/analysis.md), the learning curve of each task evaluated,
with the random policy dashed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..metrics import METRICS_FILE, read_metrics
from .runs import AnalysisError, save_png

__all__ = ["PLOT_FILE", "plot_run", "plot_run_if_possible"]

PLOT_FILE = "metrics.png"

_KNOWLEDGE = (("change_dbns", "change DBNs"), ("magnitude_dbns", "magnitude DBNs"),
              ("plans", "plans"), ("landmarks", "landmarks"),
              ("reliable_actions", "sufficiently reliable actions"))


def _series(lines: Sequence[dict[str, Any]], key: str) -> tuple[list[int], list[float]]:
    xs, ys = [], []
    for line in lines:
        v = line.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            xs.append(int(line["step"]))
            ys.append(float(v))
    return xs, ys


def _running_mean(ys: Sequence[float], window: int) -> list[float]:
    out = []
    for i in range(len(ys)):
        part = ys[max(0, i - window + 1):i + 1]
        out.append(sum(part) / len(part))
    return out


def _curve_groups(path: Path) -> list[tuple[str, list[Any], Any]]:
    """(label, checkpoint rows by step, random row or None) per task/world/trials/seed and run:
    a curve.csv of several runs (``qlap curve RUN RUN … --out DIR``) gives a line per run,
    the random policy drawn once per task."""
    from .curve import RANDOM_RUN, read_rows

    rows = read_rows(path)
    groups: dict[tuple, dict[str, Any]] = {}
    for r in rows:
        g = groups.setdefault((r.task, r.world, r.trials, r.seed), {"runs": {}, "random": None})
        if r.policy == "random" or r.run == RANDOM_RUN:
            g["random"] = r
        elif r.step is not None:
            g["runs"].setdefault(r.run, []).append(r)
    out = []
    for (task, world, trials, seed), g in sorted(groups.items()):
        label = f"{task} ({world}, {trials} trials, seed {seed})"
        for i, (run, qlap) in enumerate(g["runs"].items()):     # curve.csv's order
            named = f"{label}, {run}" if len(g["runs"]) > 1 else label
            out.append((named, sorted(qlap, key=lambda r: r.step),
                        g["random"] if i == 0 else None))
    return out


def plot_run(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Draw ``run_dir``'s metrics log (and ``curve.csv`` if any) to ``out`` (default
    ``run_dir/metrics.png``); returns the path. :class:`AnalysisError` when the run has
    neither."""
    from matplotlib.figure import Figure

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise AnalysisError(f"{run_dir}: not a run directory")
    lines = read_metrics(run_dir / METRICS_FILE)
    curve_path = run_dir / "curve.csv"
    curves = _curve_groups(curve_path) if curve_path.is_file() else []
    if not lines and not curves:
        unread = _nonblank_lines(run_dir / METRICS_FILE)
        if unread:
            raise AnalysisError(f"{run_dir / METRICS_FILE}: none of its {unread} lines is a "
                                "metrics record (a JSON object with an integer step), and no "
                                "curve.csv to draw")
        raise AnalysisError(f"{run_dir}: no {METRICS_FILE} lines and no curve.csv to draw "
                            "(runs written before the metrics log have none)")
    fig = Figure(figsize=(12.0, 8.0))
    axes = fig.subplots(2, 2)
    (ax_k, ax_iac), (ax_speed, ax_curve) = axes
    title = run_dir.resolve().name
    if lines:
        last = lines[-1]
        title += (f": {last['step']:,} steps, {last.get('dbns')} DBNs, {last.get('plans')} "
                  f"plans, {last.get('landmarks')} landmarks")
    fig.suptitle(title, fontsize=11)

    for i, (key, label) in enumerate(_KNOWLEDGE):
        xs, ys = _series(lines, key)
        if xs:
            ax_k.plot(xs, ys, color=f"C{i}", label=label)
    ax_k.set_title("knowledge", fontsize=10)
    ax_k.set_ylabel("count")

    xs, choices = _series(lines, "iac_choices")
    if xs:
        ax_iac.plot(xs, choices, color="C0", label="IAC practice choices")
    xs, babbles = _series(lines, "iac_babbles")
    if xs:
        ax_iac.plot(xs, babbles, color="C1", label="babbling commands")
    ax_iac.set_title("exploration per metrics interval", fontsize=10)
    ax_iac.set_ylabel("choices")
    calls = dict(zip(*_series(lines, "practice_calls"), strict=True))
    succ = dict(zip(*_series(lines, "practice_successes"), strict=True))
    rate = [(s, succ[s] / c) for s, c in calls.items() if c > 0 and s in succ]
    if rate:
        twin = ax_iac.twinx()
        twin.plot([s for s, _ in rate], [r for _, r in rate], color="C2", linestyle="--",
                  label="practice success rate (cumulative)")
        twin.set_ylim(0, 1)
        twin.set_ylabel("success rate")
        twin.legend(fontsize=7, loc="upper right")

    xs, sps = _series(lines, "steps_per_s")
    if xs:
        ax_speed.plot(xs, sps, color="C4", alpha=0.35, linewidth=0.8,
                      label="each metrics interval")
        window = min(10, len(sps))
        ax_speed.plot(xs, _running_mean(sps, window), color="C4",
                      label=f"mean of the last {window} intervals")
        ax_speed.set_ylim(bottom=0)
    ax_speed.set_title("speed", fontsize=10)
    ax_speed.set_ylabel("agent steps/s")

    if curves:
        for i, (label, rows, baseline) in enumerate(curves):
            color = f"C{i}"
            yerr = [0.0 if math.isnan(r.stderr) else r.stderr for r in rows]
            ax_curve.errorbar([r.step for r in rows], [r.mean_reward for r in rows],
                              yerr=yerr, fmt="o-", markersize=3, capsize=2, color=color,
                              label=label)
            if baseline is not None:                # one task's, not this run's: grey
                ax_curve.axhline(baseline.mean_reward, linestyle="--",
                                 color=color if len(curves) == 1 else "0.4",
                                 linewidth=0.9, label=f"random policy ({baseline.mean_reward:.2f})")
        ax_curve.set_ylabel("mean reward per trial")
    else:
        ax_curve.text(0.5, 0.5, "no curve.csv\n`qlap curve RUN_DIR --task TASK`\nevaluates "
                      "every checkpoint (§7.2)", ha="center", va="center", fontsize=9,
                      color="0.4", transform=ax_curve.transAxes)
        ax_curve.set_xticks([])
        ax_curve.set_yticks([])
    ax_curve.set_title("learning curve (curve.csv)", fontsize=10)

    for ax in axes.ravel():
        ax.set_xlabel("agent steps")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    target = Path(out) if out is not None else run_dir / PLOT_FILE
    try:
        return save_png(fig, target, dpi=100)
    except OSError as exc:                      # a full disk, a read-only run directory
        raise AnalysisError(f"{target}: cannot write ({exc.strerror or exc})") from None


def _nonblank_lines(path: Path) -> int:
    """How many non-blank lines ``path`` has (0 if it cannot be read)."""
    try:
        return sum(1 for raw in path.read_bytes().split(b"\n") if raw.strip())
    except OSError:
        return 0


def plot_run_if_possible(run_dir: str | Path) -> Path | None:
    """:func:`plot_run` at the end of a run: the picture, or None (with no metrics yet, or no
    matplotlib installed) — a run's results never depend on its picture."""
    try:
        return plot_run(run_dir)
    except (AnalysisError, ImportError, OSError):
        return None
