"""Knowledge over time: what each checkpoint of a run knew, and whether its DBNs stop growing.

Fig. 7.9 of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a
Developing Agent*, PhD dissertation, UT Austin, 2010 draws the number of change DBNs of a core
agent over 250,000 steps: it "does not increase without bound", with two drops (the hand's
actions becoming sufficiently reliable; DBNs deleted at age 100,000). Here every checkpoint of
a run is counted — change and magnitude DBNs, plans, landmarks, k — from its saved files
(``learner.json``, ``agent.json``; docs/checkpoint.md) without rebuilding the agent, and the
counts from 150,000 steps on are judged by :func:`growth_verdict`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from ..qlap.checkpoint import AGENT_FORMAT, FORMAT
from . import reference_values as ref
from .runs import AnalysisError, find_checkpoints, save_png

__all__ = [
    "KnowledgePoint",
    "SeriesPoint",
    "checkpoint_counts",
    "describe_verdict",
    "growth_verdict",
    "knowledge_timeline",
    "mean_series",
    "plot_dbn_counts",
    "run_speed",
    "speed_problem",
]

_LANDMARK_KINDS = ("motor", "magnitude")


@dataclass(frozen=True)
class KnowledgePoint:
    """What one checkpoint knew."""

    step: int
    """Steps the agent had observed (the N of ``step-N``)."""
    checkpoint: str
    """``step-NNNNNNN`` or ``final``."""
    change_dbns: int
    magnitude_dbns: int
    plans: int
    """Plans of the agent (§5.2), every action's counted."""
    landmarks: int
    """Landmarks of the motor and magnitude variables, the initial ones included (as
    summary.json and Table 8.1 count them)."""
    k: int
    """The window k at that checkpoint (App. C)."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _read(path: Path, fmt: str) -> dict[str, Any]:
    try:
        data = orjson.loads(path.read_bytes())
    except (OSError, orjson.JSONDecodeError) as exc:
        raise AnalysisError(f"{path}: unreadable ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != fmt:
        raise AnalysisError(f"{path}: not a {fmt} checkpoint file")
    return data


def checkpoint_counts(path: Path, step: int | None = None,
                      name: str | None = None) -> KnowledgePoint:
    """The counts of one agent checkpoint, read from its JSON files alone (no arrays, no
    agent): ``dbns`` of learner.json by ``kind``, ``plans`` of agent.json, and the landmarks of
    ``perception.spaces`` for the variables of kind motor or magnitude."""
    path = Path(path)
    learner = _read(path / "learner.json", FORMAT)
    agent = _read(path / "agent.json", AGENT_FORMAT)
    try:
        kinds = [v["kind"] for v in learner["variables"]]
        spaces = learner["perception"]["spaces"]
        dbns = learner["dbns"]
        return KnowledgePoint(
            step=int(agent["step_count"]) + 1 if step is None else step,
            checkpoint=name or path.name,
            change_dbns=sum(1 for d in dbns if d["kind"] == "change"),
            magnitude_dbns=sum(1 for d in dbns if d["kind"] == "magnitude"),
            plans=len(agent["plans"]),
            landmarks=sum(len(s) for kind, s in zip(kinds, spaces, strict=True)
                          if kind in _LANDMARK_KINDS),
            k=int(learner["k"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise AnalysisError(f"{path}: inconsistent checkpoint ({type(exc).__name__}: "
                            f"{exc})") from None


def knowledge_timeline(run_dir: Path) -> list[KnowledgePoint]:
    """The counts at every agent checkpoint of a run, by step (the checkpoints of
    :func:`.runs.find_checkpoints`: ``final`` only when no ``step-N`` has its step). A
    checkpoint directory, or a run without checkpoints, has no timeline (empty)."""
    return [checkpoint_counts(c.path, c.step, c.name)
            for c in find_checkpoints(Path(run_dir), Path(run_dir).name)]


@dataclass(frozen=True)
class SeriesPoint:
    """A count at one step across runs."""

    step: int
    mean: float
    stderr: float
    """s/√n across the runs that have this step; NaN with fewer than two."""
    n: int
    """Runs with a checkpoint at this step."""


def mean_series(timelines: Mapping[str, Sequence[KnowledgePoint]],
                field: str = "change_dbns", common: bool = False) -> list[SeriesPoint]:
    """The mean of ``field`` over the runs at each checkpoint step, with the standard error
    across the runs (§7.3). ``common``: only the steps every run has a checkpoint at."""
    by_step: dict[int, list[float]] = {}
    for points in timelines.values():
        for p in points:
            by_step.setdefault(p.step, []).append(float(getattr(p, field)))
    out = []
    for step in sorted(by_step):
        xs = np.array(by_step[step])
        if common and len(xs) < len(timelines):
            continue
        se = float(xs.std(ddof=1) / math.sqrt(len(xs))) if len(xs) > 1 else math.nan
        out.append(SeriesPoint(step, float(xs.mean()), se, len(xs)))
    return out


def growth_verdict(steps: Sequence[int], counts: Sequence[float],
                   limit: int = ref.CHANGE_DBN_LIMIT, after: int = ref.GROWTH_AFTER,
                   tolerance: float = ref.GROWTH_TOLERANCE) -> dict[str, Any]:
    """"Change DBNs ≤ ``limit`` and not growing after ``after`` steps", made precise.

    *Bounded*: the count at the last checkpoint is at most ``limit``. *Not growing*: over the
    checkpoints at or after ``after`` (at least two are needed), the least-squares line
    through (step, count) rises, from the first of them to the last, by at most ``tolerance``
    times their mean count. With the defaults (600, 150,000, 10 %) a core run holding about
    250 change DBNs may gain about 25 between 150k and 250k. A fitted line rather than two
    end points, so that one checkpoint taken just before or after a wave of deletions (age
    100,000, §6.2.3) does not decide alone. ``pass`` (bounded and not growing) is None when
    the run is too short to judge the growth.
    """
    pairs = sorted(zip(steps, counts, strict=True))
    if not pairs:
        return {"pass": None, "bounded": None, "flat": None, "limit": limit, "after": after,
                "tolerance": tolerance, "reason": "no checkpoints"}
    last_step, last = pairs[-1]
    res: dict[str, Any] = {
        "limit": limit, "after": after, "tolerance": tolerance, "last_step": int(last_step),
        "last": float(last), "bounded": bool(last <= limit)}
    window = [(s, c) for s, c in pairs if s >= after]
    res["window"] = [int(s) for s, _ in window]
    if len(window) < 2:
        res.update(flat=None, slope_per_100k=None, rise=None, allowed=None, window_mean=None,
                   reason=f"fewer than two checkpoints at or after step {after:,}")
        res["pass"] = None
        return res
    xs = np.array([s for s, _ in window], dtype=float)
    ys = np.array([c for _, c in window], dtype=float)
    slope = float(np.polyfit(xs, ys, 1)[0])
    rise = slope * float(xs[-1] - xs[0])
    allowed = tolerance * float(ys.mean())
    flat = rise <= allowed
    res.update(flat=bool(flat), slope_per_100k=slope * 1e5, rise=rise, allowed=allowed,
               window_mean=float(ys.mean()), reason="")
    res["pass"] = bool(flat and res["bounded"])
    return res


def describe_verdict(v: Mapping[str, Any]) -> str:
    """One line: pass/fail and the figures behind it."""
    head = {True: "PASS", False: "FAIL", None: "n/a"}[v["pass"]]
    if v.get("last") is None:
        return f"{head}: {v.get('reason', '')}"
    text = (f"{head}: {v['last']:.0f} change DBNs at step {v['last_step']:,} "
            f"({'≤' if v['bounded'] else '>'} {v['limit']})")
    if v["flat"] is None:
        return text + f"; growth not judged: {v['reason']}"
    return (text + f"; from step {v['after']:,} the fitted line rises {v['rise']:+.1f} "
            f"({v['slope_per_100k']:+.1f} per 100k steps) against {v['allowed']:.1f} allowed "
            f"({v['tolerance']:.0%} of the mean {v['window_mean']:.1f}): "
            + ("not growing" if v["flat"] else "growing"))


def run_speed(run_dir: Path) -> dict[str, Any] | None:
    """``steps_per_s`` and ``placement`` of a run's summary.json (None without one). The
    synchronous loop's summary names no placement. A summary.json that cannot be read gives
    ``steps_per_s`` None and a ``problem`` naming why (a truncated file is not a missing one)."""
    path = Path(run_dir) / "summary.json"
    if not path.exists():
        return None
    try:
        data = orjson.loads(path.read_bytes())
    except (OSError, orjson.JSONDecodeError) as exc:
        return _unreadable(f"summary.json unreadable: {exc}")
    if not isinstance(data, dict):
        return _unreadable("summary.json is not a JSON object")
    sps = data.get("steps_per_s")
    return {"steps_per_s": None if sps is None else float(sps),
            "placement": data.get("placement", "sync"), "steps": data.get("steps"),
            "wall_time_s": data.get("wall_time_s")}


def _unreadable(problem: str) -> dict[str, Any]:
    return {"steps_per_s": None, "placement": None, "steps": None, "wall_time_s": None,
            "problem": problem}


def speed_problem(sp: Mapping[str, Any] | None) -> str:
    """Why a run has no speed to show: no summary.json, an unreadable one, or no
    ``steps_per_s`` in it."""
    if sp is None:
        return "no summary.json"
    return str(sp.get("problem") or "no steps_per_s in summary.json")


def plot_dbn_counts(timelines: Mapping[str, Sequence[KnowledgePoint]], path: Path,
                    title: str, field: str = "change_dbns",
                    targets: ref.WorldTargets = ref.CORE_TARGETS) -> None:
    """Change DBNs against steps, as Fig. 7.9: the mean across runs with standard-error bars
    (at the steps every run has), each run faintly, the reference's ≈ 250 (when the chapter-8
    figures apply to the world of ``targets``), the limit of 600 and the step from which
    growth is judged. Written as PNG (matplotlib's Agg canvas)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.5))
    ax = fig.subplots()
    many = len(timelines) > 1
    if many:
        for i, (_label, pts) in enumerate(sorted(timelines.items())):
            ax.plot([p.step for p in pts], [getattr(p, field) for p in pts], color="0.75",
                    linewidth=0.8, label="each run" if i == 0 else None)
    series = mean_series(timelines, field, common=True)   # no mean over a changing set of runs
    if series:
        yerr = [0.0 if math.isnan(p.stderr) else p.stderr for p in series]
        ax.errorbar([p.step for p in series], [p.mean for p in series], yerr=yerr, fmt="o-",
                    markersize=3, capsize=2, color="C0",
                    label=(f"mean of {len(timelines)} runs (± s.e. across runs)" if many
                           else next(iter(timelines), "run")))
    if field == "change_dbns":
        if targets.chapter_8:
            ax.axhline(ref.CHANGE_DBNS, linestyle=":", color="C2",
                       label=f"reference ≈ {ref.CHANGE_DBNS} (Fig. 7.9)")
        ax.axhline(targets.change_dbn_limit, linestyle="--", color="C3",
                   label=f"limit {targets.change_dbn_limit}")
        last = max((p.step for pts in timelines.values() for p in pts), default=0)
        if last >= targets.growth_after:
            ax.axvline(targets.growth_after, linestyle="-.", color="0.5", linewidth=0.8,
                       label=f"growth judged from {targets.growth_after:,}")
    ax.set_xlabel("agent steps")
    ax.set_ylabel({"change_dbns": "change DBNs", "magnitude_dbns": "magnitude DBNs"}.get(
        field, field.replace("_", " ")))
    ax.set_ylim(bottom=0)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_png(fig, path)
