"""Statistics as §7.3 does them: means with standard errors, and repeated-measures ANOVA.

§7.3 of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a Developing
Agent*, PhD dissertation, UT Austin, 2010: each condition has twenty agents, every checkpoint
is evaluated, "all error bars are standard error", bar graphs show "the average performance
over time" with "the first 100,000 timesteps ... excluded", and the significance is a
repeated-measures ANOVA over the same checkpoints, reported as F and sig.

The design is mixed (split-plot): the condition varies between agents, the checkpoint within
each agent. The reference's F tests are the between-subjects effect of condition — their
degrees of freedom are those of 20 + 20 independent agents (e.g. Fig. 7.2(f): F = 2.358, sig.
0.133, which is F(1, 38)). With every agent evaluated at the same checkpoints, that test
equals a one-way ANOVA of the agents' averages over the checkpoints (the within-subject sums of
squares cancel), which :func:`between_anova` computes with statsmodels' ``ols`` and
``anova_lm``; agents missing a checkpoint of the window are left out (listwise, as SPSS does).
statsmodels' ``AnovaRM`` handles within-subject factors only; :func:`time_anova` uses it for the
effect of the checkpoint within one condition ("does it still improve?").
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "AnovaResult",
    "Point",
    "between_anova",
    "complete_agents",
    "curve",
    "format_f",
    "mean_se",
    "time_anova",
    "window_means",
]

AgentSeries = Mapping[str, Mapping[int, float]]
"""Each agent's value at each step: {agent: {step: value}}."""


@dataclass(frozen=True)
class Point:
    """The mean across agents at one step."""

    step: int
    mean: float
    stderr: float
    """s/√n; NaN with fewer than two agents."""
    n: int


@dataclass(frozen=True)
class AnovaResult:
    """An F test."""

    F: float
    df1: float
    df2: float
    sig: float
    """p-value (SPSS's "sig.")."""
    n: tuple[int, ...]
    """Agents in each group (or subjects, for the time effect)."""

    def caption(self) -> str:
        return format_f(self.F, self.sig)


def format_f(F: float | None, sig: float | None) -> str:
    """``F = 71.740, sig. = 0.000`` as the reference's captions print it."""
    if F is None or sig is None or not math.isfinite(F):
        return "—"
    return f"F = {F:.3f}, sig. = {sig:.3f}"


def mean_se(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean, standard error s/√n (NaN for n < 2) and n."""
    x = np.asarray(list(values), dtype=float)
    if len(x) == 0:
        return math.nan, math.nan, 0
    se = float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else math.nan
    return float(x.mean()), se, len(x)


def curve(series: AgentSeries) -> list[Point]:
    """The mean and standard error across agents at every step any agent has."""
    steps = sorted({s for v in series.values() for s in v})
    out = []
    for s in steps:
        m, se, n = mean_se([v[s] for v in series.values() if s in v])
        out.append(Point(s, m, se, n))
    return out


def complete_agents(series: AgentSeries, steps: Sequence[int]) -> dict[str, list[float]]:
    """The agents that have a value at every one of ``steps``, with those values."""
    return {a: [v[s] for s in steps] for a, v in series.items() if all(s in v for s in steps)}


def window_means(series: AgentSeries, after: int) -> dict[str, float]:
    """Each agent's average over the steps after ``after`` that the agents have (agents missing
    one of them left out)."""
    steps = sorted({s for v in series.values() for s in v if s > after})
    return {a: float(np.mean(x)) for a, x in complete_agents(series, steps).items() if x}


def between_anova(groups: Mapping[str, Sequence[float]]) -> AnovaResult | None:
    """The between-subjects F test of a mixed ANOVA, from each agent's average over the
    window (one-way ANOVA via statsmodels ``ols`` + ``anova_lm``). None when a group has no
    agent, or there is no variance to test."""
    import pandas as pd
    from statsmodels.formula.api import ols
    from statsmodels.stats.anova import anova_lm

    data = [(g, float(y)) for g, ys in groups.items() for y in ys]
    sizes = tuple(len(ys) for ys in groups.values())
    if len(groups) < 2 or min(sizes) < 1 or len(data) <= len(groups):
        return None
    frame = pd.DataFrame(data, columns=["group", "y"])
    if float(frame["y"].var(ddof=0)) == 0.0:
        return None
    table = anova_lm(ols("y ~ C(group)", data=frame).fit(), typ=1)
    F = float(table.loc["C(group)", "F"])
    p = float(table.loc["C(group)", "PR(>F)"])
    if not math.isfinite(F):
        return None
    return AnovaResult(F, float(table.loc["C(group)", "df"]),
                       float(table.loc["Residual", "df"]), p, sizes)


def time_anova(series: AgentSeries, after: int) -> AnovaResult | None:
    """The within-subject effect of the checkpoint over the steps after ``after``, by
    statsmodels' ``AnovaRM`` (agents complete on those steps only). None with fewer than two
    steps or agents, or no variance."""
    import pandas as pd
    from statsmodels.stats.anova import AnovaRM

    steps = sorted({s for v in series.values() for s in v if s > after})
    agents = complete_agents(series, steps)
    if len(steps) < 2 or len(agents) < 2:
        return None
    frame = pd.DataFrame([(a, s, y) for a, ys in agents.items()
                          for s, y in zip(steps, ys, strict=True)],
                         columns=["agent", "step", "y"])
    if float(frame["y"].var(ddof=0)) == 0.0:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        table = AnovaRM(frame, "y", "agent", within=["step"]).fit().anova_table
    F = float(table["F Value"].iloc[0])
    if not math.isfinite(F):
        return None
    return AnovaResult(F, float(table["Num DF"].iloc[0]), float(table["Den DF"].iloc[0]),
                       float(table["Pr > F"].iloc[0]), (len(agents),))
