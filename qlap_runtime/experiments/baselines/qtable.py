"""Tabular Q-learning on landmarks: QLAP's against random ones (§7.7).

§7.7 of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a Developing
Agent*, PhD dissertation, UT Austin, 2010 judges the landmarks by the tabular Q-learner they
make: "QLAP landmarks" are those a QLAP agent learned in 100,000 steps of the 2D core world;
"random landmarks" are, for each magnitude or motor variable, 0–5 landmarks placed uniformly
within the range observed in a typical run (a motor keeps its landmark at 0, so it has 1–6).

The state: every magnitude's qualitative value (below the first landmark, on a landmark
[lb, ub], between two, above the last: index 0 … 2n), every magnitude's direction of change
(three bins, as the agent's), every nominal variable's value and the goal. The actions: for
each motor, one per qualitative value of its landmarks within its range — an open interval's
midpoint or a landmark's centre — setting that motor and leaving the others at rest, so the
motor landmarks decide what the learner can do, as they do for QLAP. Q-learning with
App. H's α = 0.2, γ = 1, ε = 0.05 (§7.7 states none); one decision every step.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..spec import QTableConfig
from . import common
from .sarsa import epsilon_greedy

__all__ = [
    "QTableAgent",
    "landmark_actions",
    "load_policy",
    "qlap_landmarks",
    "qualitative_index",
    "random_landmarks",
    "train",
]

Landmarks = dict[str, list[tuple[float, float]]]


def qualitative_index(x: float, landmarks: Sequence[tuple[float, float]]) -> int:
    """The qualitative value of ``x`` among sorted landmarks [lb, ub]: 2i for the interval
    below landmark i, 2i + 1 on it, 2n above the last."""
    for i, (lb, ub) in enumerate(landmarks):
        if x < lb:
            return 2 * i
        if x <= ub:
            return 2 * i + 1
    return 2 * len(landmarks)


def qlap_landmarks(knowledge: Mapping[str, Any]) -> Landmarks:
    """The landmarks ([lb, ub], sorted) of every motor and magnitude variable of a QLAP
    agent's knowledge (knowledge.json, docs/outputs.md), the initial ones included."""
    out: Landmarks = {}
    for name, lms in knowledge["landmarks"].items():
        out[name] = sorted((float(m["lb"]), float(m["ub"])) for m in lms)
    return out


def random_landmarks(world: Any, ranges: Mapping[str, tuple[float, float]],
                     rng: np.random.Generator, most: int = 5) -> Landmarks:
    """§7.7.2: for each magnitude or motor variable, 0..``most`` landmarks uniformly within
    its range (a magnitude's observed one, a motor's own); motors also keep 0."""
    out: Landmarks = {}
    for v in world.variables:
        kind = v.kind.value
        if kind == "motor":
            lo, hi = float(v.low), float(v.high)
        elif kind == "magnitude":
            lo, hi = ranges[v.name]
        else:
            continue
        points = [float(p) for p in rng.uniform(lo, hi, int(rng.integers(0, most + 1)))]
        if kind == "motor" and lo < 0.0 < hi:
            points.append(0.0)
        out[v.name] = sorted((p, p) for p in points)
    return out


def landmark_actions(world: Any, landmarks: Mapping[str, Sequence[tuple[float, float]]]
                     ) -> list[dict[str, float]]:
    """One action per motor and qualitative value of its landmarks within its range (an open
    interval's midpoint, a landmark's centre), the other motors at rest; duplicates dropped."""
    out: list[dict[str, float]] = []
    rest = False                                   # one action leaves every motor at rest
    for v in world.variables:
        if v.kind.value != "motor":
            continue
        lo, hi = float(v.low), float(v.high)
        lms = [(max(lb, lo), min(ub, hi)) for lb, ub in landmarks.get(v.name, ())
               if ub >= lo and lb <= hi]
        values = []
        edge = lo
        for lb, ub in lms:
            if lb > edge:
                values.append((edge + lb) / 2)
            values.append((lb + ub) / 2)
            edge = ub
        if edge < hi:
            values.append((edge + hi) / 2)
        for x in dict.fromkeys(round(x, 9) for x in values):
            if x == 0.0:
                if rest:
                    continue
                rest = True
            out.append({v.name: float(x)})
    return out


class QTableAgent:
    """One-step Q-learning over the qualitative state of some landmarks."""

    def __init__(self, world: Any, config: QTableConfig, landmarks: Landmarks,
                 rng: np.random.Generator,
                 table: Mapping[str, Sequence[float]] | None = None) -> None:
        self.config = config
        self.rng = rng
        self.names = common.magnitudes(world)
        self.nominals = [v.name for v in world.variables if v.kind.value == "nominal"]
        self.landmarks = {n: list(landmarks.get(n, ())) for n in self.names}
        self.actions = landmark_actions(world, landmarks)
        self.q: dict[str, np.ndarray] = {k: np.asarray(v, dtype=float)
                                         for k, v in (table or {}).items()}
        self._sa: tuple[str, int] | None = None

    def encode(self, world: Any, obs: Mapping[str, float], goal: Any) -> str:
        parts = [str(qualitative_index(obs[n], self.landmarks[n])) if n in obs else "-"
                 for n in self.names]
        parts += [str(common.change_bin(world, n, self.config.change_band)) for n in self.names]
        parts += [str(int(obs[n])) if n in obs else "-" for n in self.nominals]
        parts.append(f"{goal.variable}={goal.value}")
        return ",".join(parts)

    def values(self, state: str) -> np.ndarray:
        q = self.q.get(state)
        if q is None:
            q = self.q[state] = np.zeros(len(self.actions))
        return q

    def start(self, state: str) -> int:
        a = epsilon_greedy(self.values(state), self.config.epsilon, self.rng)
        self._sa = (state, a)
        return a

    def step(self, reward: float, state: str) -> int:
        if self._sa is None:
            raise RuntimeError("QTableAgent.step before start")
        s, a = self._sa
        target = reward + self.config.gamma * float(self.values(state).max())
        q = self.values(s)
        q[a] += self.config.alpha * (target - q[a])
        return self.start(state)

    def end(self, reward: float) -> None:
        if self._sa is None:
            raise RuntimeError("QTableAgent.end before start")
        s, a = self._sa
        q = self.values(s)
        q[a] += self.config.alpha * (reward - q[a])
        self._sa = None

    def act(self, state: str, rng: np.random.Generator) -> int:
        q = self.q.get(state)
        if q is None:
            q = np.zeros(len(self.actions))
        return epsilon_greedy(q, self.config.eval_epsilon, rng)


def train(world: Any, world_spec: str, tasks: tuple[str, ...], steps: int, seed: int,
          config: QTableConfig, landmarks: Landmarks, out: Path, checkpoint_every: int,
          progress: common.ProgressFn | None = None) -> dict[str, Any]:
    """Practise the tasks for ``steps`` steps; checkpoints into ``out/checkpoints``."""
    agent = QTableAgent(world, config, landmarks, np.random.default_rng([seed, 2]))
    meta = {"kind": "qtable", "world": world_spec, "seed": seed, "tasks": list(tasks),
            "config": dataclasses.asdict(config),
            "landmarks": {k: [list(x) for x in v] for k, v in landmarks.items()},
            "actions": agent.actions}

    def save(t: int) -> None:
        name = common.checkpoint_name(t, steps, checkpoint_every)
        if name is not None:
            keys = sorted(agent.q)
            table = np.array([agent.q[k] for k in keys]).reshape(len(keys), len(agent.actions))
            common.save_checkpoint(Path(out) / "checkpoints" / name,
                                   {**meta, "step": t, "states": keys}, {"q": table})

    summary = common.practice(world, tasks, steps, seed, agent, 1, None, save, progress)
    summary["states"] = len(agent.q)
    summary["actions"] = len(agent.actions)
    return summary


def load_policy(checkpoint: Path, world: Any) -> common.HeldPolicy:
    """The policy of a Q-table checkpoint for ``world``'s trials (learning off)."""
    meta, arrays = common.load_checkpoint(checkpoint)
    config = QTableConfig(**meta["config"])
    landmarks = {k: [(float(a), float(b)) for a, b in v] for k, v in meta["landmarks"].items()}
    table = dict(zip(meta["states"], arrays["q"], strict=True))
    agent = QTableAgent(world, config, landmarks, np.random.default_rng(0), table)
    return common.HeldPolicy(agent, 1)

