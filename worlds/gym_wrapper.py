"""``gym:ENV_ID`` — any Gymnasium environment with a Box observation space as a world.

Each observation dimension becomes a magnitude variable and each action dimension a motor with
the Box's bounds as its range (a Discrete action space becomes one motor over [0, n − 1], rounded
to the nearest action). Names come from ``obs_names`` / ``act_names`` (options of ``make``), or
from the built-in table :data:`NAMES` for a few classic-control environments, or are ``obs_i`` /
``act_i``. ``step_seconds`` is the env's ``dt`` when it has one (Pendulum-v1: 0.05; MuJoCo envs:
timestep × frame skip), else 1.0 (a step is the time unit). When an episode terminates or is
truncated the environment is reset (seeded from the world's generator) and the observation after
that reset is returned: the agent sees one endless stream, in which that step is marked as a
discontinuity. Rewards are ignored (QLAP learns without them); ``episodes`` counts the restarts.

Gymnasium's passive environment checker is turned off (``disable_env_checker=True``): this
wrapper checks actions itself against the variable table, and the checker's warnings would be
errors under the test suite's ``filterwarnings = error``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import MappingProxyType
from typing import Any

import numpy as np

from worlds.base import VariableSpec, VarKind, World

__all__ = ["NAMES", "GymWorld", "make_gym"]

#: Readable variable names for some classic-control environments: (observation, action).
NAMES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "Pendulum-v1": (("cos_theta", "sin_theta", "theta_dot"), ("torque",)),
    "MountainCarContinuous-v0": (("position", "velocity"), ("force",)),
    "MountainCar-v0": (("position", "velocity"), ("push",)),
    "CartPole-v1": (("cart_x", "cart_v", "pole_angle", "pole_omega"), ("push",)),
    "Acrobot-v1": (
        ("cos_theta1", "sin_theta1", "cos_theta2", "sin_theta2", "omega1", "omega2"),
        ("torque",),
    ),
}


def _step_seconds(dt: object) -> float:
    """The env's ``dt`` (seconds per step) when it has a positive one, else 1.0."""
    if isinstance(dt, int | float) and not isinstance(dt, bool) and math.isfinite(dt) and dt > 0:
        return float(dt)
    return 1.0


class GymWorld(World):
    """A Gymnasium environment with a Box observation space, seen as a world."""

    substeps = 1

    def __init__(
        self,
        env_id: str,
        obs_names: Sequence[str] | None = None,
        act_names: Sequence[str] | None = None,
        **make_kwargs: Any,
    ) -> None:
        import gymnasium as gym
        from gymnasium import spaces

        self.env_id = env_id
        self.name = f"gym:{env_id}"
        self.env = gym.make(env_id, disable_env_checker=True, **make_kwargs)
        obs_space, act_space = self.env.observation_space, self.env.action_space
        if not isinstance(obs_space, spaces.Box):
            self.env.close()
            raise ValueError(f"{env_id}: observation space {obs_space} is not a Box")
        default_obs, default_act = NAMES.get(env_id, ((), ()))
        n_obs = int(np.prod(obs_space.shape))
        self.discrete = isinstance(act_space, spaces.Discrete)
        if self.discrete:
            lows, highs = np.array([0.0]), np.array([float(act_space.n - 1)])  # type: ignore[attr-defined]
        elif isinstance(act_space, spaces.Box):
            lows = np.asarray(act_space.low, dtype=float).ravel()
            highs = np.asarray(act_space.high, dtype=float).ravel()
            if not (np.isfinite(lows).all() and np.isfinite(highs).all()):
                self.env.close()
                raise ValueError(f"{env_id}: action space {act_space} has infinite bounds")
        else:
            self.env.close()
            raise ValueError(f"{env_id}: action space {act_space} is neither Box nor Discrete")
        obs_names = tuple(obs_names or default_obs or (f"obs_{i}" for i in range(n_obs)))
        act_names = tuple(act_names or default_act or (f"act_{i}" for i in range(len(lows))))
        if len(obs_names) != n_obs or len(act_names) != len(lows):
            self.env.close()
            raise ValueError(
                f"{env_id}: {n_obs} observation and {len(lows)} action dimensions, "
                f"got names {obs_names} and {act_names}"
            )
        self._act_shape = act_space.shape
        self._act_dtype = act_space.dtype
        self._obs_names = obs_names
        variables = tuple(
            VariableSpec(n, VarKind.MOTOR, f"{env_id} action dimension {i}", float(lo), float(hi))
            for i, (n, lo, hi) in enumerate(zip(act_names, lows, highs, strict=True))
        ) + tuple(
            VariableSpec(n, VarKind.MAGNITUDE, f"{env_id} observation dimension {i}")
            for i, n in enumerate(obs_names)
        )
        self._init_variables(variables)
        self.tasks = MappingProxyType({})
        self.agent_options = MappingProxyType({})
        self.episodes = 0
        self.step_seconds = _step_seconds(getattr(self.env.unwrapped, "dt", None))
        self.reset(seed=0)

    def _as_obs(self, raw: Any) -> dict[str, float]:
        return dict(
            zip(self._obs_names, np.asarray(raw, dtype=float).ravel().tolist(), strict=True)
        )

    def _restart(self) -> dict[str, float]:
        raw, _ = self.env.reset(seed=int(self.rng.integers(2**31 - 1)))
        self.episodes += 1
        return self._as_obs(raw)

    def _reset(self) -> dict[str, float]:
        self.episodes = 0
        self.env.action_space.seed(int(self.rng.integers(2**31 - 1)))
        return self._restart()

    def _step(self, motor: list[float]) -> dict[str, float]:
        if self.discrete:
            action: Any = round(motor[0])
        else:
            action = np.asarray(motor, dtype=self._act_dtype).reshape(self._act_shape)
        raw, _reward, terminated, truncated, _info = self.env.step(action)
        if terminated or truncated:
            self._mark_discontinuity()
            return self._restart()
        return self._as_obs(raw)

    def close(self) -> None:
        self.env.close()


def make_gym(variant: str | None = None, option: str | None = None, **options: Any) -> GymWorld:
    """Registry factory for ``gym:ENV_ID`` (an env id with a ':' is given whole)."""
    if not variant:
        raise ValueError("gym needs an environment id, e.g. 'gym:Pendulum-v1'")
    env_id = variant if option is None else f"{variant}:{option}"
    return GymWorld(env_id, **options)
