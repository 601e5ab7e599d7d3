"""What a run knows, beside the reference's figures (``qlap report``).

The figures of the project's knowledge table (docs/results.md), from a run's knowledge
(docs/outputs.md): the window k (App. C), the number of change and magnitude DBNs (Fig. 7.9),
landmarks per variable (Table 8.1), slivers (qualitative values narrower than the variable's
resolution), the u_x landmarks at the friction threshold (Table 8.1, §8.1.1) and rel(a) of three
actions with whether each has a plan (Tables 8.2, 8.4, 8.5) of J. Mugan, *Autonomous
Qualitative Learning of Distinctions and Actions in a Developing Agent*, PhD dissertation, UT
Austin, 2010. The reference's values live in :mod:`.reference_values`.

Beside the final figures: the knowledge over time of each run (change and magnitude DBNs,
plans, landmarks at every checkpoint, :mod:`.timeline`) with the verdict "change DBNs ≤ 600 and
not growing after 150k", and the run's speed (summary.json's ``steps_per_s``).
"""

from __future__ import annotations

import json
import math
import re
import statistics
import unicodedata
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..telemetry import pretty
from . import reference_values as ref
from .markdown import num
from .runs import AnalysisError, load_knowledge, read_summary, recorded_world, run_labels
from .timeline import (
    KnowledgePoint,
    describe_verdict,
    growth_verdict,
    knowledge_timeline,
    mean_series,
    run_speed,
    speed_problem,
)

__all__ = [
    "format_report",
    "format_timeline",
    "knowledge_figures",
    "main_report",
    "narrow_values",
    "reference_figures",
    "report_data",
    "resolutions_of",
]


def _span(a: float, b: float, resolution: float | None) -> float:
    """The width below which a value between a and b is a sliver."""
    if resolution is not None and resolution > 0:
        return resolution
    return ref.NARROW_RELATIVE * max(abs(a), abs(b))


def narrow_values(landmarks: Sequence[Mapping[str, Any]],
                  resolution: float | None = None) -> list[dict[str, Any]]:
    """The qualitative values of a variable narrower than its resolution (or, without one, than
    0.1 % of their magnitude): landmark ranges [lb, ub] with lb < ub, and the open intervals
    between consecutive landmarks. Point landmarks are not slivers by themselves."""
    out: list[dict[str, Any]] = []
    prev: float | None = None
    for m in sorted(landmarks, key=lambda m: float(m["lb"])):
        lb, ub = float(m["lb"]), float(m["ub"])
        if prev is not None and lb - prev < _span(prev, lb, resolution):
            out.append({"value": f"({prev:.6g}, {lb:.6g})", "width": lb - prev,
                        "limit": _span(prev, lb, resolution)})
        if lb < ub and ub - lb < _span(lb, ub, resolution):
            out.append({"value": m.get("label", f"[{lb:.6g}, {ub:.6g}]"), "width": ub - lb,
                        "limit": _span(lb, ub, resolution)})
        prev = ub
    return out


def _find_action(knowledge: Mapping[str, Any], variable: str,
                 value: str) -> Mapping[str, Any] | None:
    for a in knowledge.get("actions", []):
        if a["variable"] == variable and a["value"] == value:
            return a
    return None



def unsigned_zero(label: str) -> str:
    """A landmark label with a zero written as ``0``, never ``-0`` (as the UI writes it)."""
    return re.sub(r"(?<![\d.])-0(?![\d.e])", "0", label)


def knowledge_figures(knowledge: Mapping[str, Any],
                      resolutions: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The report's figures of one run's knowledge (a knowledge.json object)."""
    resolutions = resolutions or {}
    dbns = knowledge.get("dbns", [])
    lms: Mapping[str, list] = knowledge.get("landmarks", {})
    counts = {v: len(m) for v, m in lms.items()}
    narrow = [dict(n, variable=v) for v, m in lms.items()
              for n in narrow_values(m, resolutions.get(v))]
    lo, hi = ref.FRICTION_BAND

    def centre(m: Mapping[str, Any]) -> float:
        return (float(m["lb"]) + float(m["ub"])) / 2

    u_x = None
    if "u_x" in lms:
        u_x = {"landmarks": [unsigned_zero(m["label"]) for m in lms["u_x"]],
               "plus": [unsigned_zero(m["label"]) for m in lms["u_x"]
                        if lo <= centre(m) <= hi],
               "minus": [unsigned_zero(m["label"]) for m in lms["u_x"]
                         if -hi <= centre(m) <= -lo]}
    actions = {}
    for ra in ref.ACTIONS:
        a = _find_action(knowledge, ra.variable, ra.value)
        actions[f"a({ra.variable}, {ra.value})"] = {
            "rel": None if a is None else float(a["reliability"]),
            "plan": bool(a and a["plans"]), "plans": 0 if a is None else len(a["plans"]),
            "calls": 0 if a is None else int(a["calls"])}
    top = max(counts, key=lambda v: counts[v]) if counts else None
    return {
        "step": knowledge.get("step"), "k": knowledge.get("k"),
        "k_learned": knowledge.get("k_learned"),
        "change_dbns": sum(1 for d in dbns if d.get("kind") == "change"),
        "magnitude_dbns": sum(1 for d in dbns if d.get("kind") == "magnitude"),
        "landmarks": counts,
        "landmarks_median": statistics.median(counts.values()) if counts else None,
        "landmarks_max": counts[top] if top is not None else None,
        "landmarks_max_variable": top,
        "narrow": narrow, "narrow_count": len(narrow),
        "narrow_rule": "resolution" if resolutions else "0.1 % of the value",
        "u_x": u_x, "actions": actions,
    }


def reference_figures() -> dict[str, Any]:
    """The reference's values and the project's targets (docs/results.md), as JSON."""
    counts = dict(ref.LANDMARKS_TABLE_8_1)
    return {
        "k": {"value": ref.WINDOW_K, "target": ref.TARGETS["k"],
              "source": "App. C, §7.10.1"},
        "change_dbns": {"value": ref.CHANGE_DBNS, "target": ref.TARGETS["change_dbns"],
                        "source": "Fig. 7.9"},
        "landmarks": counts,
        "landmarks_median": statistics.median(counts.values()),
        "landmarks_max": max(counts.values()),
        "landmarks_target": {"median": ref.TARGETS["landmarks_median"],
                             "max": ref.TARGETS["landmarks_max"]},
        "narrow_count": 0, "narrow_target": ref.TARGETS["narrow_count"],
        "growth": {"limit": ref.CHANGE_DBN_LIMIT, "after": ref.GROWTH_AFTER,
                   "tolerance": ref.GROWTH_TOLERANCE,
                   "target": "change DBNs ≤ 600 at the end; the least-squares line through "
                             "the counts from 150k on rises by ≤ 10 % of their mean"},
        "steps_per_s": {"target": ref.SYNC_STEPS_PER_S,
                        "what": "summary.json steps_per_s of the sync loop, mean over runs"},
        "u_x": {"landmarks": [list(r) for r in ref.U_X_LANDMARKS],
                "band": list(ref.FRICTION_BAND), "target": ref.TARGETS["u_x_band"],
                "source": "Table 8.1"},
        "actions": {f"a({a.variable}, {a.value})": {"rel": a.rel, "target": a.target,
                                                     "source": a.source}
                    for a in ref.ACTIONS},
    }


def resolutions_of(path: Path) -> dict[str, float]:
    """Each motor's and magnitude's resolution, as the learner of the run's final checkpoint
    (or of checkpoint ``path``) defines it, ``Perception.resolution``. Empty when there is no
    checkpoint or the learner defines none; the report then uses the 0.1 % rule."""
    from ..qlap.checkpoint import CheckpointError, load_learner, resolve_checkpoint
    from ..qlap.variables import Kind

    path = resolve_checkpoint(path)
    candidates = [path, resolve_checkpoint(path / "checkpoints" / "final")]
    for d in candidates:
        if not (d / "learner.json").is_file():
            continue
        try:
            learner = load_learner(d)
        except CheckpointError:
            return {}
        resolution = getattr(learner.perception, "resolution", None)
        if resolution is None:
            return {}
        return {v.name: float(resolution(v.index))
                for v in learner.table.of_kind(Kind.MOTOR, Kind.MAGNITUDE)}
    return {}


def _mean(values: Sequence[float | None]) -> float | None:
    xs = [float(v) for v in values if v is not None]
    return sum(xs) / len(xs) if xs else None


def format_report(figures: Sequence[dict[str, Any]], labels: Sequence[str]) -> str:
    """The knowledge table: one row per measure, the reference, one column per run and the mean."""
    R = reference_figures()
    many = len(figures) > 1
    header = ["measure", "reference", "target", *labels] + (["mean"] if many else [])
    rows: list[list[str]] = []
    T = ref.TARGETS

    def row(measure: str, reference: str, target: str, cells: list[str],
            mean: str = "") -> None:
        rows.append([measure, reference, target, *cells] + ([mean] if many else []))

    ks = [f["k"] for f in figures]
    row("window k (App. C)", f"≈ {R['k']['value']} (§7.10.1)", T["k"],
        [num(f["k"]) + (" (not learned)" if f["k_learned"] is False else "")
         for f in figures],
        num(_mean(ks), "{:.1f}"))
    for key, name, reference in (
            ("change_dbns", "change DBNs (Fig. 7.9)", f"≈ {ref.CHANGE_DBNS}, bounded"),
            ("magnitude_dbns", "magnitude DBNs", "—")):
        vals = [f[key] for f in figures]
        row(name, reference, T.get(key, "—"), [str(v) for v in vals],
            num(_mean(vals), "{:.1f}"))
    med = [f["landmarks_median"] for f in figures]
    row("landmarks per variable, median", f"{R['landmarks_median']:g} (Table 8.1)",
        T["landmarks_median"], [num(m) for m in med], num(_mean(med), "{:.2f}"))
    top = [f["landmarks_max"] for f in figures]
    row("landmarks per variable, max", f"{R['landmarks_max']} (Table 8.1)",
        T["landmarks_max"], [f"{f['landmarks_max']} ({pretty(f['landmarks_max_variable'])})"
         if f["landmarks_max"] is not None else "—" for f in figures],
        num(_mean(top), "{:.1f}"))
    nar = [f["narrow_count"] for f in figures]
    row("values narrower than resolution / 0.1 %", "none", T["narrow_count"],
        [str(n) for n in nar],
        num(_mean(nar), "{:.1f}"))
    lo, hi = ref.FRICTION_BAND
    (m0, m1), (p0, p1) = ref.U_X_LANDMARKS
    for side, band, reference in (("plus", f"[{lo:g}, {hi:g}]", f"[{p0}, {p1}]"),
                                  ("minus", f"[−{hi:g}, −{lo:g}]", f"[{m0}, {m1}]")):
        cells = []
        for f in figures:
            u = f["u_x"]
            cells.append("n/a" if u is None else (", ".join(u[side]) or "none"))
        have = sum(1 for f in figures if f["u_x"] and len(f["u_x"][side]) == 1)
        row(f"u_x landmarks centred in {band}", reference, T["u_x_band"], cells,
            f"{have}/{len(figures)} runs with one")
    for ra in ref.ACTIONS:
        key = f"a({ra.variable}, {ra.value})"
        acts = [f["actions"][key] for f in figures]
        cells = [("—" if a["rel"] is None else f"{a['rel']:.2f}")
                 + (" plan" if a["plan"] else " no plan") for a in acts]
        planned = sum(1 for a in acts if a["plan"])
        row(f"rel {pretty(key)} ({ra.source})", f"{ra.rel:.2f}",
            f"≥ {ra.target:.2f}, a plan", cells,
            f"{num(_mean([a['rel'] for a in acts]), '{:.2f}')}, plan {planned}/{len(acts)}")
    # knowledge.json's step is the index t of the last step (0-based): t + 1 steps were done,
    # the N of the step-N checkpoint and of the UI's count
    steps = [num(None if f["step"] is None else f["step"] + 1, "{:,}") for f in figures]
    lines = [f"knowledge after {', '.join(steps)} steps", "", _table(header, rows)]

    variables = list(dict.fromkeys([*(v for v in ref.LANDMARKS_TABLE_8_1
                                       if any(v in f["landmarks"] for f in figures)),
                                    *(v for f in figures for v in f["landmarks"])]))
    per_var = []
    for v in variables:
        counts = [f["landmarks"].get(v) for f in figures]
        refc = ref.LANDMARKS_TABLE_8_1.get(v)
        per_var.append([pretty(v), "—" if refc is None else str(refc),
                        *[num(c) for c in counts]]
                       + ([num(_mean(counts), "{:.1f}")] if many else []))
    lines += ["", "landmarks per variable (initial ones included, as Table 8.1):",
              _table(["variable", "Table 8.1", *labels] + (["mean"] if many else []), per_var)]
    for f, label in zip(figures, labels, strict=True):
        head = f"{label}: " if many else ""
        if f["u_x"] is not None:
            lines += ["", f"{head}u_x landmarks: {', '.join(f['u_x']['landmarks'])}"]
        if f["narrow"]:
            shown = f["narrow"][:12]
            lines += ["", f"{head}narrow values ({len(f['narrow'])}, narrower than "
                          f"{f['narrow_rule']}):"]
            lines += [f"  {pretty(n['variable']):8s} {n['value']}  width {n['width']:.3g} "
                      f"< {n['limit']:.3g}" for n in shown]
            if len(f["narrow"]) > len(shown):
                lines.append("  …")
    return "\n".join(lines)


def _width(text: str) -> int:
    """Columns a string takes in a terminal (ḣ is h and a combining dot)."""
    return sum(0 if unicodedata.combining(ch) else 1 for ch in text)


def _table(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(_width(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(cells: list[str]) -> str:
        return "  ".join(c + " " * (w - _width(c))
                         for c, w in zip(cells, widths, strict=True)).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def format_timeline(timelines: Mapping[str, Sequence[KnowledgePoint]],
                    verdicts: Mapping[str, Mapping[str, Any]],
                    mean_verdict: Mapping[str, Any] | None,
                    speeds: Mapping[str, Mapping[str, Any] | None]) -> str:
    """Knowledge over time (one row per checkpoint step, one column per run: change DBNs /
    magnitude DBNs / plans / landmarks), the growth verdicts and the runs' speeds."""
    labels = list(timelines)
    many = len(labels) > 1
    lines = ["knowledge over time (change DBNs / magnitude DBNs / plans / landmarks at each "
             "checkpoint):"]
    steps = sorted({p.step for pts in timelines.values() for p in pts})
    if not steps:
        lines.append("  no checkpoints")
    else:
        at = {label: {p.step: p for p in pts} for label, pts in timelines.items()}
        mean = {p.step: p for p in mean_series(timelines)}
        rows = []
        for step in steps:
            cells = []
            for label in labels:
                p = at[label].get(step)
                cells.append("" if p is None else
                             f"{p.change_dbns} / {p.magnitude_dbns} / {p.plans} / {p.landmarks}")
            extra = []
            if many:
                m = mean[step]
                extra = [f"{m.mean:.1f}" + ("" if math.isnan(m.stderr) else f" ± {m.stderr:.1f}")
                         + ("" if m.n == len(labels) else f" ({m.n} of {len(labels)} runs)")]
            rows.append([f"{step:,}", *cells, *extra])
        lines.append(_table(["step", *labels] + (["mean change DBNs (± s.e.)"] if many else []),
                            rows))
    lines += ["", f"change DBNs ≤ {ref.CHANGE_DBN_LIMIT} and not growing after "
                  f"{ref.GROWTH_AFTER:,} steps (least-squares rise over the checkpoints from "
                  f"{ref.GROWTH_AFTER:,} on ≤ {ref.GROWTH_TOLERANCE:.0%} of their mean):"]
    width = max(len(x) for x in [*labels, "mean"])
    for label in labels:
        lines.append(f"  {label:<{width}}  {describe_verdict(verdicts[label])}")
    if many and mean_verdict is not None:
        lines.append(f"  {'mean':<{width}}  {describe_verdict(mean_verdict)}")
    lines += ["", f"speed (summary.json steps_per_s; target ≥ {ref.SYNC_STEPS_PER_S:,.0f} "
                  "steps/s for the sync loop):"]
    for label in labels:
        sp = speeds.get(label)
        lines.append(f"  {label:<{width}}  " + (
            speed_problem(sp) if sp is None or sp["steps_per_s"] is None else
            f"{sp['steps_per_s']:,.1f} steps/s ({sp['placement']})"))
    values = [sp["steps_per_s"] for sp in speeds.values() if sp and sp["steps_per_s"]]
    if many and values:
        lines.append(f"  {'mean':<{width}}  {sum(values) / len(values):,.1f} steps/s "
                     f"over {len(values)} run(s)")
    return "\n".join(lines)


def report_data(paths: Sequence[Path],
                targets: ref.WorldTargets = ref.CORE_TARGETS) -> dict[str, Any]:
    """Everything ``qlap report --json`` prints, as a dict: ``reference``, ``runs`` (each run's
    final figures), ``mean``, ``timeline`` (each run's counts at every checkpoint),
    ``growth`` (each run's verdict), ``growth_mean`` (the verdict on the mean across runs at
    the checkpoint steps they all have), ``speed`` (each run's summary.json speed). The growth
    verdicts use the limit, first step and tolerance of ``targets`` (core's by default)."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise AnalysisError("give at least one run directory")
    labels = run_labels(paths)
    worlds = {w for p in paths if (w := _world_of(p)) is not None}
    if len(worlds) > 1:
        raise AnalysisError(f"the runs are in different worlds ({', '.join(sorted(worlds))}); "
                            "one report compares runs of one world")
    figures = [knowledge_figures(load_knowledge(p), resolutions_of(p)) for p in paths]
    timelines = {label: knowledge_timeline(p) if (p / "checkpoints").is_dir() else []
                 for label, p in zip(labels, paths, strict=True)}
    rule = {"limit": targets.change_dbn_limit, "after": targets.growth_after,
            "tolerance": targets.growth_tolerance}
    growth = {label: growth_verdict([q.step for q in pts], [q.change_dbns for q in pts], **rule)
              for label, pts in timelines.items()}
    common = mean_series(timelines, common=True)
    growth_mean = growth_verdict([q.step for q in common], [q.mean for q in common], **rule)
    speeds = {label: run_speed(p) for label, p in zip(labels, paths, strict=True)}
    mean: dict[str, Any] = {key: _mean([f[key] for f in figures])
            for key in ("k", "change_dbns", "magnitude_dbns", "landmarks_median",
                        "landmarks_max", "narrow_count")}
    mean["actions"] = {key: {"rel": _mean([f["actions"][key]["rel"] for f in figures]),
                             "with_plan": sum(f["actions"][key]["plan"] for f in figures)}
                       for key in figures[0]["actions"]}
    mean["steps_per_s"] = _mean([sp["steps_per_s"] for sp in speeds.values() if sp])
    return {"reference": reference_figures(),
            "runs": dict(zip(labels, figures, strict=True)), "mean": mean,
            "timeline": {label: [q.to_json() for q in pts] for label, pts in timelines.items()},
            "growth": growth, "growth_mean": growth_mean, "speed": speeds}


def _world_of(path: Path) -> str | None:
    """The world a run (its summary.json) or a checkpoint (what it records) was learned in."""
    summary = read_summary(path)
    if summary is not None and isinstance(summary.get("world"), str):
        return summary["world"]
    for where in (path, path / "checkpoints" / "final"):
        try:
            world = recorded_world(where)
        except (OSError, ValueError):
            continue
        if world is not None:
            return world
    return None


def main_report(paths: Sequence[Path], as_json: bool = False) -> str:
    """``qlap report``: the figures of each run (a run or checkpoint directory) as text or
    JSON (:func:`report_data`); knowledge that is not a run's (a wrong type, a missing field)
    is an :class:`AnalysisError` naming the runs."""
    try:
        return _report_text(paths, as_json)
    except AnalysisError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise AnalysisError(f"{', '.join(map(str, paths))}: malformed knowledge "
                            f"({type(exc).__name__}: {exc})") from None


def _report_text(paths: Sequence[Path], as_json: bool) -> str:
    data = report_data(paths)
    if as_json:
        return json.dumps(data, indent=1, ensure_ascii=False)
    labels = list(data["runs"])
    timelines = {label: [KnowledgePoint(**q) for q in pts]
                 for label, pts in data["timeline"].items()}
    return "\n\n".join([
        format_report([data["runs"][label] for label in labels], labels),
        format_timeline(timelines, data["growth"],
                        data["growth_mean"] if len(labels) > 1 else None, data["speed"])])
