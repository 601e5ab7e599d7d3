"""Tile-1 and Tile-10: Sarsa(λ) with tile coding on the core tasks (§7.4, Appendix H).

Appendix H of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a
Developing Agent*, PhD dissertation, UT Austin, 2010: 16 tilings, memory 65,536; u_x and u_y
each in 10 equal-width bins, 20 actions each setting one of them; change variables in 3 bins
(−∞, −0.05), [−0.05, 0.05], (0.05, ∞); the goal a discrete variable; the other variables
continuous, normalised to [0, 1] by the minimum and maximum of a typical run; generalization
0.25; λ = 0.9, γ = 1.0, α = 0.2; ε-greedy with ε = 0.05. Tile-10 chooses an action every 10
steps and pays −0.1 a decision (§7.4.2).

The state of a step: every magnitude, normalised and divided by the generalization (floats of
:class:`~.tiles.TileCoder`); the integers are each magnitude's change bin, each nominal
variable's value, the goal (:func:`~.common.goal_code`) and, last, the action. The motors are
the action, not part of the state. All inputs go into one hashed tiling, as tiles.C does with
one call.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..spec import TileConfig
from . import common
from .sarsa import SarsaLambda, epsilon_greedy
from .tiles import TileCoder

__all__ = ["TileAgent", "load_policy", "train"]


class TileAgent:
    """Sarsa(λ) over the tile coding of a world's variables (App. H)."""

    def __init__(self, world: Any, config: TileConfig, ranges: Mapping[str, tuple[float, float]],
                 rng: np.random.Generator, theta: np.ndarray | None = None) -> None:
        self.config = config
        self.names = common.magnitudes(world)
        self.nominals = [v.name for v in world.variables if v.kind.value == "nominal"]
        lo = np.array([ranges[n][0] for n in self.names], dtype=float)
        hi = np.array([ranges[n][1] for n in self.names], dtype=float)
        self.lo = lo
        self.span = np.where(hi > lo, hi - lo, 1.0)
        self.actions = common.bin_actions(world, config.motors, config.motor_bins)
        self.coder = TileCoder(config.tilings, config.memory)
        self.learner = SarsaLambda(config.memory, config.alpha, config.lam, config.gamma,
                                   config.epsilon, rng, config.tilings, theta)

    def inputs(self, world: Any, obs: Mapping[str, float],
               goal: Any) -> tuple[np.ndarray, list[int]]:
        """(floats, ints) of the tile coder for this observation and goal."""
        x = np.array([obs.get(n, np.nan) for n in self.names], dtype=float)
        norm = np.clip((x - self.lo) / self.span, 0.0, 1.0)
        floats = np.where(np.isnan(x), 0.0, norm) / self.config.generalization
        ints = [common.change_bin(world, n, self.config.change_band) for n in self.names]
        ints += [int(obs[n]) if n in obs else -1 for n in self.nominals]
        ints.append(common.goal_code(goal))
        return floats, ints

    def encode(self, world: Any, obs: Mapping[str, float], goal: Any) -> np.ndarray:
        """The tiles of (state, a) for every action: (actions, tilings)."""
        floats, ints = self.inputs(world, obs, goal)
        return self.coder.action_tiles(floats, ints, len(self.actions))

    def start(self, state: np.ndarray) -> int:
        return self.learner.start(state)

    def step(self, reward: float, state: np.ndarray) -> int:
        return self.learner.step(reward, state)

    def end(self, reward: float) -> None:
        self.learner.end(reward)

    def act(self, state: np.ndarray, rng: np.random.Generator) -> int:
        return epsilon_greedy(self.learner.values(state), self.config.eval_epsilon, rng)


def _config(data: Mapping[str, Any]) -> TileConfig:
    d = dict(data)
    d["motors"] = tuple(d["motors"])
    return TileConfig(**d)


def train(world: Any, world_spec: str, tasks: tuple[str, ...], steps: int, seed: int,
          config: TileConfig, ranges: Mapping[str, tuple[float, float]], out: Path,
          checkpoint_every: int, progress: common.ProgressFn | None = None) -> dict[str, Any]:
    """Practise the tasks for ``steps`` world steps; checkpoints into ``out/checkpoints``."""
    agent = TileAgent(world, config, ranges, np.random.default_rng([seed, 1]))
    meta = {"kind": "tile", "world": world_spec, "seed": seed, "tasks": list(tasks),
            "config": dataclasses.asdict(config), "ranges": {k: list(v) for k, v in
                                                             ranges.items()}}

    def save(t: int) -> None:
        name = common.checkpoint_name(t, steps, checkpoint_every)
        if name is not None:
            common.save_checkpoint(Path(out) / "checkpoints" / name, {**meta, "step": t},
                                   {"theta": agent.learner.theta})

    return common.practice(world, tasks, steps, seed, agent, config.decision_every,
                           config.decision_cost, save, progress)


def load_policy(checkpoint: Path, world: Any) -> common.HeldPolicy:
    """The policy of a Tile-N checkpoint for ``world``'s trials (learning off)."""
    meta, arrays = common.load_checkpoint(checkpoint)
    config = _config(meta["config"])
    ranges = {k: (float(v[0]), float(v[1])) for k, v in meta["ranges"].items()}
    agent = TileAgent(world, config, ranges, np.random.default_rng(0), arrays["theta"])
    return common.HeldPolicy(agent, config.decision_every)
