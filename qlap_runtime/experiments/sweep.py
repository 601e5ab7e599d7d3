"""An experiment expanded into agent runs and evaluations, and where their results live.

Every agent of an arm is one *run* (:class:`RunSpec`): a kind (QLAP, a tile coder, a
Q-table), a world, its steps, its seed (agent i has seed i + 1) and everything else that
decides what it learns. Its directory, ``OUT/agents/KEY/``, is named by a hash of that spec, so
the same run is shared by every experiment that needs it (QLAP in the core world serves
core-tasks, extraneous, dbn-count and ablations) and is never computed twice. It holds what
``qlap run --out`` writes (``summary.json``, ``checkpoints/``; docs/outputs.md), ``run.json``
(the spec) and ``curve.csv`` (its evaluations, the format of ``qlap curve``,
docs/analysis.md). The random policy's evaluations go to ``OUT/random/curve.csv``.

Every evaluated checkpoint and task is one :class:`EvalSpec`: §7.2's protocol, ``trials``
trials with trial seed 0 (the same set-ups for every checkpoint, as ``qlap curve``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..analysis.curve import RANDOM_RUN, CurveRow, read_rows
from .spec import Arm, Experiment, QTableConfig, TileConfig

__all__ = [
    "EVAL_SEED",
    "EvalSpec",
    "RunSpec",
    "Sweep",
    "checkpoint_steps",
    "plan",
    "run_done",
]

EVAL_SEED = 0
"""Seed of the evaluation trials: every checkpoint meets the same trial set-ups."""


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", text)


@dataclass(frozen=True)
class RunSpec:
    """One agent learning: everything that decides its checkpoints."""

    kind: str
    """``qlap``, ``tile`` or ``qtable``."""
    world: str
    steps: int
    seed: int
    checkpoint_every: int
    params: tuple[tuple[str, Any], ...] = ()
    ablations: tuple[str, ...] = ()
    tile: TileConfig | None = None
    qtable: QTableConfig | None = None
    tasks: tuple[str, ...] = ()
    """The tasks a baseline practises (§7.4.2)."""
    landmark_run: str | None = None
    """The key of the QLAP run whose landmarks a Q-learner uses (§7.7)."""

    def to_json(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> RunSpec:
        d = dict(d)
        d["params"] = tuple((k, v) for k, v in d.get("params") or ())
        d["ablations"] = tuple(d.get("ablations") or ())
        d["tasks"] = tuple(d.get("tasks") or ())
        if d.get("tile") is not None:
            t = dict(d["tile"])
            t["motors"] = tuple(t["motors"])
            d["tile"] = TileConfig(**t)
        if d.get("qtable") is not None:
            d["qtable"] = QTableConfig(**d["qtable"])
        return cls(**d)

    @property
    def label(self) -> str:
        """The learner in a word: ``qlap`` (``+ablations``), ``tile1``, ``tile10``,
        ``qtable_qlap``, ``qtable_random``."""
        if self.tile is not None:
            return f"tile{self.tile.decision_every}"
        if self.qtable is not None:
            return f"qtable_{self.qtable.landmarks}"
        return "+".join([self.kind, *self.ablations])

    @property
    def key(self) -> str:
        """``LABEL-WORLD-STEPS-sSEED-HASH``: the run's directory name (the hash covers the
        whole spec)."""
        text = json.dumps(self.to_json(), sort_keys=True, separators=(",", ":"))
        digest = hashlib.sha256(text.encode()).hexdigest()[:10]
        return f"{self.label}-{_safe(self.world)}-{self.steps}-s{self.seed}-{digest}"

    def last_checkpoint(self) -> str:
        return (f"step-{self.steps:07d}" if self.steps % self.checkpoint_every == 0
                else "final")


def checkpoint_steps(steps: int, every: int) -> list[tuple[int, str]]:
    """(step, name) of a run's checkpoints: every multiple of ``every``, and ``final`` at the
    last step when it is not one."""
    out = [(s, f"step-{s:07d}") for s in range(every, steps + 1, every)]
    if steps % every:
        out.append((steps, "final"))
    return out


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation: a checkpoint (or the random policy) on a task."""

    run: str
    """The run's key, or ``random``."""
    kind: str
    """The run's kind, or ``random``."""
    step: int | None
    checkpoint: str
    world: str
    task: str
    trials: int
    seed: int = EVAL_SEED

    @property
    def policy(self) -> str:
        return "random" if self.kind == "random" else self.kind

    @property
    def key(self) -> tuple[str, str, int | None, str, str, int, int]:
        """The key of its row in curve.csv (:attr:`CurveRow.key`)."""
        return (self.policy, self.run, self.step, self.world, self.task, self.trials,
                self.seed)

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ArmRuns:
    """The runs of one arm and how they are drawn."""

    arm: Arm
    runs: tuple[str, ...]
    """One run key per agent."""
    offset: int
    """Drawn at step − offset."""
    eval_world: str
    steps: tuple[int, ...]
    """The evaluated checkpoint steps (before the offset)."""


@dataclass
class Sweep:
    """The runs and evaluations of a configured experiment under one output root."""

    experiment: Experiment
    root: Path
    runs: dict[str, RunSpec] = field(default_factory=dict)
    evals: list[EvalSpec] = field(default_factory=list)
    arms: dict[str, ArmRuns] = field(default_factory=dict)

    def run_dir(self, key: str) -> Path:
        return self.root / "agents" / key

    def curve_path(self, run: str) -> Path:
        return self.root / "random" / "curve.csv" if run == RANDOM_RUN \
            else self.run_dir(run) / "curve.csv"

    @property
    def out(self) -> Path:
        """The experiment's own directory (figures, tables, RESULTS.md)."""
        suffix = "-quick" if self.experiment.quick_mode else ""
        return self.root / f"{self.experiment.name}{suffix}"

    def rows(self) -> dict[tuple[Any, ...], CurveRow]:
        """Every evaluation already recorded for this sweep's runs (and the random policy)."""
        out: dict[tuple[Any, ...], CurveRow] = {}
        for run in [RANDOM_RUN, *self.runs]:
            for r in read_rows(self.curve_path(run)):
                out[r.key] = r
        return out


def _landmark_run(exp: Experiment, arm: Arm, seed: int) -> RunSpec | None:
    """The QLAP run whose landmarks a Q-learner of ``arm`` uses (§7.7.2), if any."""
    q = arm.condition.qtable
    if q is None or q.landmarks != "qlap":
        return None
    steps = q.landmark_steps or arm.steps(exp.steps)
    if exp.quick_mode:
        steps = min(steps, exp.steps)
    return RunSpec("qlap", arm.world_spec(exp.steps), steps, seed, exp.checkpoint_every,
                   arm.condition.params, arm.condition.ablations)


def _run_spec(exp: Experiment, arm: Arm, seed: int) -> RunSpec:
    cond = arm.condition
    steps = arm.steps(exp.steps)
    world = arm.world_spec(exp.steps)
    if cond.kind == "qlap":
        return RunSpec("qlap", world, steps, seed, exp.checkpoint_every, cond.params,
                       cond.ablations)
    if cond.kind == "tile":
        return RunSpec("tile", world, steps, seed, exp.checkpoint_every, tile=cond.tile,
                       tasks=exp.tasks)
    assert cond.qtable is not None
    landmark_run = _landmark_run(exp, arm, seed)
    return RunSpec("qtable", world, steps, seed, exp.checkpoint_every, qtable=cond.qtable,
                   tasks=exp.tasks, landmark_run=landmark_run.key if landmark_run else None)


def plan(exp: Experiment, root: Path) -> Sweep:
    """The runs and evaluations of a configured experiment (:func:`.spec.configure`)."""
    sweep = Sweep(exp, Path(root))
    evals: dict[tuple[Any, ...], EvalSpec] = {}
    for arm in exp.arms:
        keys = []
        eval_world = arm.evaluation_world(exp.steps)
        eval_from = round(arm.eval_from_fraction * exp.steps)
        for i in range(exp.agents):
            spec = _run_spec(exp, arm, seed=i + 1)
            dep = _landmark_run(exp, arm, seed=i + 1)
            if dep is not None:
                sweep.runs.setdefault(dep.key, dep)
            sweep.runs.setdefault(spec.key, spec)
            keys.append(spec.key)
        steps = [s for s, _ in checkpoint_steps(arm.steps(exp.steps), exp.checkpoint_every)
                 if (s % exp.eval_every == 0 or s == arm.steps(exp.steps))
                 and (eval_from == 0 or s > eval_from)]
        sweep.arms[arm.label] = ArmRuns(arm, tuple(keys), arm.offset(exp.steps), eval_world,
                                        tuple(steps))
        for key in keys:
            spec = sweep.runs[key]
            names = dict(checkpoint_steps(spec.steps, spec.checkpoint_every))
            for task in exp.tasks:
                for s in steps:
                    e = EvalSpec(key, spec.kind, s, names[s], eval_world, task, exp.trials)
                    evals.setdefault(e.key, e)
        for task in exp.tasks:
            e = EvalSpec(RANDOM_RUN, "random", None, "", eval_world, task, exp.trials)
            evals.setdefault(e.key, e)
    sweep.evals = list(evals.values())
    return sweep


def run_done(run_dir: Path, spec: RunSpec) -> bool:
    """A finished run: its ``summary.json`` says it ran ``spec.steps`` steps, its ``run.json``
    is this spec, and its last checkpoint is there."""
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
        recorded = json.loads((run_dir / "run.json").read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(summary, dict) or summary.get("steps") != spec.steps:
        return False
    if recorded.get("spec") != spec.to_json():
        return False
    last = run_dir / "checkpoints" / spec.last_checkpoint()
    return (last / "agent.json").is_file() or (last / "meta.json").is_file()
