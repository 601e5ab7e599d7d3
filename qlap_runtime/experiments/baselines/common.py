"""What the baselines share: practice on a world's tasks, inputs, actions, checkpoints.

The baselines of J. Mugan, *Autonomous Qualitative Learning of Distinctions and Actions in a
Developing Agent*, PhD dissertation, UT Austin, 2010 — Sarsa(λ) with tile coding (§7.4,
App. H) and tabular Q-learning on landmarks (§7.7) — learn from the task's reward: they
"repeatedly performed trials of a particular core task", the task "chosen randomly" at the
beginning of each trial (§7.4.2). A trial is the §7.2 protocol (:mod:`worlds.evaluate`): the
task's set-up, its goal, −0.01 a step (or the decision's cost) and 9.99 on success, at most
300 steps; it ends on success, on failure or at the limit.

Inputs. Magnitudes are normalised to [0, 1] by the minimum and maximum of
:func:`babble_ranges` (App. H: "observed during a typical run of QLAP", whose first 20,000
steps are motor babbling, App. E); change variables are their direction of change per second in
three bins (−∞, −0.05), [−0.05, 0.05], (0.05, ∞) (App. H, Table 8.1), the middle one on a
discontinuity; nominal variables and the goal are integers.

Checkpoints are directories ``checkpoints/step-NNNNNNN/`` (and ``final`` when the last step is
not a multiple of the interval) holding ``meta.json`` and ``.npy`` arrays (no pickle), each
written to a temporary directory and renamed.
"""

from __future__ import annotations

import json
import math
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ...qlap.checkpoint import atomic_write_bytes, write_checkpoint_dir

__all__ = [
    "BABBLE_MAX_HOLD",
    "Agent",
    "HeldPolicy",
    "babble_ranges",
    "bin_actions",
    "cached_ranges",
    "change_bin",
    "checkpoint_name",
    "goal_code",
    "load_checkpoint",
    "magnitudes",
    "practice",
    "save_checkpoint",
]

BABBLE_MAX_HOLD = 40
"""Each motor holds a random value for 0..40 steps while babbling (App. E)."""

ProgressFn = Callable[[int], None]


def magnitudes(world: Any) -> list[str]:
    """The magnitude variables of a world, in its order."""
    return [v.name for v in world.variables if v.kind.value == "magnitude"]


def babble_ranges(world: Any, steps: int, seed: int = 0) -> dict[str, tuple[float, float]]:
    """The minimum and maximum of every magnitude over ``steps`` steps of motor babbling
    (App. E: each motor holds a uniform random value for 0..40 steps)."""
    rng = np.random.default_rng(seed)
    motors = [v for v in world.variables if v.kind.value == "motor"]
    values = np.zeros(len(motors))
    left = np.zeros(len(motors), dtype=np.int64)
    names = magnitudes(world)
    lo = dict.fromkeys(names, math.inf)
    hi = dict.fromkeys(names, -math.inf)

    def see(obs: Mapping[str, float]) -> None:
        for n in names:
            x = obs.get(n)
            if x is not None:
                lo[n] = min(lo[n], x)
                hi[n] = max(hi[n], x)

    see(world.reset(seed=seed))
    for _ in range(steps):
        for i, m in enumerate(motors):
            if left[i] <= 0:
                values[i] = rng.uniform(m.low, m.high)
                left[i] = rng.integers(0, BABBLE_MAX_HOLD + 1) + 1
            left[i] -= 1
        see(world.step({m.name: float(v) for m, v in zip(motors, values, strict=True)}))
    return {n: (lo[n], hi[n]) if lo[n] <= hi[n] else (0.0, 1.0) for n in names}


def cached_ranges(world_spec: str, steps: int, cache_dir: Path,
                  seed: int = 0) -> dict[str, tuple[float, float]]:
    """:func:`babble_ranges` of a world spec, computed once into
    ``cache_dir/<world>-<steps>-s<seed>.json``."""
    import worlds

    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in world_spec)
    path = Path(cache_dir) / f"{safe}-{steps}-s{seed}.json"
    try:
        data = json.loads(path.read_text())
        return {k: (float(v[0]), float(v[1])) for k, v in data["ranges"].items()}
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        pass
    world = worlds.make(world_spec)
    try:
        ranges = babble_ranges(world, steps, seed)
    finally:
        world.close()
    atomic_write_bytes(path, json.dumps({"world": world_spec, "steps": steps, "seed": seed,
                                         "ranges": ranges}, indent=1).encode())
    return ranges


def change_bin(world: Any, name: str, band: float) -> int:
    """The direction of change of ``name`` at the world's latest step, per second: 0 below
    −band, 1 within [−band, band] (and on a discontinuity or when absent), 2 above band."""
    if world.discontinuity:
        return 1
    cur, prev = world.observation.get(name), world.previous_observation.get(name)
    if cur is None or prev is None:
        return 1
    d = (cur - prev) / world.step_seconds
    return 0 if d < -band else 2 if d > band else 1


def goal_code(goal: Any) -> int:
    """A goal (variable, qualitative value) as a stable integer (CRC-32 of ``variable=value``)."""
    return zlib.crc32(f"{goal.variable}={goal.value}".encode())


def bin_actions(world: Any, motors: Sequence[str], bins: int) -> list[dict[str, float]]:
    """One action per motor and equal-width bin of its range, setting that motor to the bin's
    centre and leaving the others at rest (App. H: u_x and u_y in 10 bins, 20 actions)."""
    specs = {v.name: v for v in world.variables if v.kind.value == "motor"}
    missing = [m for m in motors if m not in specs]
    if missing:
        raise ValueError(f"{world.name} has no motor {missing[0]!r}")
    out = []
    for m in motors:
        lo, hi = float(specs[m].low), float(specs[m].high)
        out += [{m: lo + (k + 0.5) * (hi - lo) / bins} for k in range(bins)]
    return out


class Agent(Protocol):
    """A baseline learner: states from observations, actions, and one episode's updates."""

    actions: list[dict[str, float]]

    def encode(self, world: Any, obs: Mapping[str, float], goal: Any) -> Any: ...
    def start(self, state: Any) -> int: ...
    def step(self, reward: float, state: Any) -> int: ...
    def end(self, reward: float) -> None: ...
    def act(self, state: Any, rng: np.random.Generator) -> int: ...


def checkpoint_name(step: int, steps: int, every: int) -> str | None:
    """``step-NNNNNNN`` at every multiple of ``every``; ``final`` at the last step when it is
    not one (as ``qlap run`` names an agent's checkpoints); None otherwise."""
    if step % every == 0:
        return f"step-{step:07d}"
    if step == steps:
        return "final"
    return None


def practice(world: Any, tasks: Sequence[str], steps: int, seed: int, agent: Agent,
             decision_every: int, decision_cost: float | None,
             save: Callable[[int], None], progress: ProgressFn | None = None
             ) -> dict[str, Any]:
    """Trials of tasks chosen at random until ``steps`` world steps (§7.4.2). A decision holds
    its action for ``decision_every`` steps (or until the trial ends) and earns the success
    reward if the goal is reached during it, else ``decision_cost`` (None: the task's step cost
    times the steps taken). ``save(step)`` is called after every world step."""
    rng = np.random.default_rng(seed)
    t = trials = successes = 0
    t0 = time.perf_counter()
    while t < steps:
        task = world.tasks[tasks[int(rng.integers(len(tasks)))]]
        obs = task.setup(world, rng)
        a = agent.start(agent.encode(world, obs, task.goal(world, obs)))
        trials += 1
        taken = 0
        while True:
            success = failure = False
            n = 0
            while n < decision_every:
                obs = world.step(agent.actions[a])
                t += 1
                taken += 1
                n += 1
                save(t)
                if progress is not None:
                    progress(t)
                if task.is_success(world, obs):
                    success = True
                    break
                if task.is_failure(world, obs) or taken >= task.max_steps or t >= steps:
                    failure = True
                    break
            if success:
                successes += 1
                reward = task.success_reward
            else:
                reward = decision_cost if decision_cost is not None else task.step_cost * n
            if failure or (success and task.episodic):
                agent.end(reward)
                break
            a = agent.step(reward, agent.encode(world, obs, task.goal(world, obs)))
    wall = time.perf_counter() - t0
    return {"steps": t, "trials": trials, "successes": successes,
            "wall_time_s": round(wall, 3), "steps_per_s": round(t / wall, 1) if wall else None}


class HeldPolicy:
    """A trained baseline as a policy for :func:`worlds.evaluate.run_trials` (learning off):
    a new action every ``decision_every`` steps of a trial, ε-greedy with the trial's
    generator."""

    def __init__(self, agent: Agent, decision_every: int) -> None:
        self.agent = agent
        self.every = decision_every
        self.action = 0
        self.held = 0

    def __call__(self, world: Any, obs: Mapping[str, float], goal: Any,
                 rng: np.random.Generator) -> Mapping[str, float]:
        if world.step_count == 0:
            self.held = 0
        if self.held % self.every == 0:
            self.action = self.agent.act(self.agent.encode(world, obs, goal), rng)
        self.held += 1
        return self.agent.actions[self.action]


def save_checkpoint(directory: Path, meta: Mapping[str, Any],
                    arrays: Mapping[str, np.ndarray]) -> Path:
    """``directory`` with ``meta.json`` and one ``NAME.npy`` per array, written whole or not
    at all (``write_checkpoint_dir``; an older one is replaced)."""

    def write(tmp: Path) -> None:
        for name, arr in arrays.items():
            with open(tmp / f"{name}.npy", "wb") as f:
                np.save(f, np.asarray(arr), allow_pickle=False)
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True))

    return write_checkpoint_dir(directory, write, merge=False)


def load_checkpoint(directory: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """``meta.json`` and the ``.npy`` arrays of a baseline checkpoint (no pickle)."""
    directory = Path(directory)
    meta = json.loads((directory / "meta.json").read_text())
    arrays = {p.stem: np.load(p, allow_pickle=False) for p in sorted(directory.glob("*.npy"))}
    return meta, arrays
