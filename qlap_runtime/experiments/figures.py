"""The figures of chapter 7, in the reference's layout (matplotlib, Agg canvas, PNG).

J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a Developing Agent*,
PhD dissertation, UT Austin, 2010 draws each task as learning curves (mean reward per trial
against timesteps, standard-error bars, one line per condition: sub-figures (a)–(c) of
Figs. 7.2–7.4) above bar graphs of the average after the first 100,000 timesteps with the F
test in the caption ((d)–(f)); the change DBNs over time per condition (Figs. 7.9, 7.24); the
cumulative calls to sets of actions (Figs. 7.21–7.23). :func:`plot_task` draws one task's
panels (curves on top, their bars below), :func:`plot_series` a count over time per condition.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..analysis.runs import save_png
from .stats import Point

__all__ = ["PanelData", "plot_series", "plot_task"]


class PanelData:
    """What one panel shows: each arm's curve and bar, and the captions of its tests."""

    def __init__(self, key: str, title: str, curves: Mapping[str, Sequence[Point]],
                 bars: Mapping[str, tuple[float, float, int]], captions: Sequence[str]) -> None:
        self.key, self.title = key, title
        self.curves, self.bars, self.captions = curves, bars, list(captions)


def _save(fig: object, path: Path) -> None:
    save_png(fig, path, dpi=100)


def _colors(labels: Sequence[str]) -> dict[str, str]:
    return {label: f"C{i % 10}" for i, label in enumerate(labels)}


def plot_task(task: str, panels: Sequence[PanelData], random_reward: float | None,
              after: int, path: Path, title: str, arm_order: Sequence[str]) -> None:
    """One task: the panels' learning curves on top, their bar graphs (the average of the
    checkpoints after ``after``) below, with the F tests under each bar graph."""
    from matplotlib.figure import Figure

    n = max(1, len(panels))
    width = max(7.0, 4.6 * n)
    fig = Figure(figsize=(width, 8.0), layout="constrained")
    axes = fig.subplots(2, n, squeeze=False)
    colors = _colors(arm_order)
    letters = "abcdefghijklmnop"
    for i, p in enumerate(panels):
        ax = axes[0][i]
        for arm, pts in p.curves.items():
            if not pts:
                continue
            yerr = [0.0 if math.isnan(q.stderr) else q.stderr for q in pts]
            ax.errorbar([q.step for q in pts], [q.mean for q in pts], yerr=yerr, fmt="o-",
                        markersize=3, capsize=2, color=colors.get(arm), label=arm)
        if random_reward is not None:
            ax.axhline(random_reward, linestyle="--", color="0.4", linewidth=0.9,
                       label=f"random policy ({random_reward:.2f})")
        if after > 0:
            ax.axvline(after, linestyle=":", color="0.6", linewidth=0.8)
        ax.set_title(f"({letters[i]}) {p.title}", fontsize=9)
        ax.set_xlim(left=0)
        ax.set_xlabel("timesteps", fontsize=8)
        ax.set_ylabel("average reward per trial", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        bx = axes[1][i]
        arms = [a for a in p.curves if a in p.bars and not math.isnan(p.bars[a][0])]
        means = [p.bars[a][0] for a in arms]
        errs = [0.0 if math.isnan(p.bars[a][1]) else p.bars[a][1] for a in arms]
        bx.bar(range(len(arms)), means, yerr=errs, capsize=4,
               color=[colors.get(a, "C0") for a in arms])
        bx.set_xticks(range(len(arms)), arms, fontsize=7, rotation=20 if len(arms) > 3 else 0)
        bx.axhline(0.0, color="0.3", linewidth=0.6)
        bx.set_ylabel(f"average after {after:,} steps" if after else "average over all steps",
                      fontsize=8)
        bx.tick_params(labelsize=7)
        bx.set_title(f"({letters[n + i]})", fontsize=9)
        if p.captions:
            chars = int(width / n * 14)
            bx.set_xlabel("\n".join(textwrap.fill(c, chars) for c in p.captions), fontsize=7)
    fig.suptitle(textwrap.fill(title, int(width * 11)), fontsize=10)
    _save(fig, path)


def plot_series(series: Mapping[str, Sequence[Point]], path: Path, title: str, ylabel: str,
                reference: float | None = None, reference_label: str = "") -> None:
    """A count over time per condition, mean ± standard error across agents (Figs. 7.9,
    7.21–7.25)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.5), layout="constrained")
    ax = fig.subplots()
    colors = _colors(list(series))
    for arm, pts in series.items():
        if not pts:
            continue
        yerr = [0.0 if math.isnan(q.stderr) else q.stderr for q in pts]
        ax.errorbar([q.step for q in pts], [q.mean for q in pts], yerr=yerr, fmt="o-",
                    markersize=3, capsize=2, color=colors[arm], label=arm)
    if reference is not None:
        ax.axhline(reference, linestyle=":", color="0.4", label=reference_label)
    ax.set_xlabel("timesteps")
    ax.set_ylabel(ylabel)
    ax.set_ylim(bottom=0)
    ax.set_xlim(left=0)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)
