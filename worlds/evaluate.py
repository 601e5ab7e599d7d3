"""Evaluation trials (§7.2.1): a task's trials run with a policy; here the random-motor baseline.

``run_random_trials(world, task_name, n_trials, seed)`` runs ``n_trials`` trials of a task with
a policy that draws every motor uniformly from its range at each step (or holds the motors at 0
when the task says an agent without a plan does so, §7.9.1), and reports the mean reward. Any
other policy (the agent in goal mode, ``qlap_runtime.agent_run.goal_policy``; a trained tile
coder) runs through :func:`run_trials` on the same set-ups.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from worlds.base import Goal, Task, VarKind, World
from worlds.check import random_motor

__all__ = ["Policy", "run_random_trials", "run_trials"]

#: A policy maps (world, observation, goal, rng) to motor values.
Policy = Callable[[World, Mapping[str, float], Goal, np.random.Generator], Mapping[str, float]]



def no_task(world: str, task: str, tasks: Iterable[str]) -> str:
    """One line for a task the world does not have: its tasks, and where the others are."""
    return (f"{world} has no task {task!r}; its tasks: {', '.join(sorted(tasks)) or 'none'} "
            "(qlap worlds lists every world's tasks; choose the world with --world)")

def _random_policy(task: Task) -> Policy:
    def policy(
        world: World, obs: Mapping[str, float], goal: Goal, rng: np.random.Generator
    ) -> Mapping[str, float]:
        if task.hold_motors_at_zero_without_plan:
            return {v.name: 0.0 for v in world.variables if v.kind is VarKind.MOTOR}
        return random_motor(world, rng)

    return policy


def run_trials(
    world: World, task_name: str, n_trials: int, seed: int, policy: Policy
) -> dict[str, Any]:
    """Run ``n_trials`` trials of ``world.tasks[task_name]`` with ``policy``.

    Returns ``mean_reward``, ``std_reward``, ``rewards`` (per trial), ``successes`` (number of
    successful steps: trials that reached the goal, or volleys for a non-episodic task),
    ``failures`` (trials ended early), ``timeouts``, ``mean_steps``, and ``by_goal``: the same
    counts for each goal a trial started with (``"T_L.dot=+"``; move_block draws one of three,
    §7.2.2 footnote 2), so that a weak goal shows.

    The trials' set-ups (block, hand, goal) draw from ``seed`` alone and the policy from a
    stream of its own (``SeedSequence(seed, spawn_key=(1,))``), so every policy — the agent at
    each checkpoint, the random baseline, a tile coder — meets the same set-ups.
    """
    if task_name not in world.tasks:
        raise ValueError(no_task(world.name, task_name, world.tasks))
    task = world.tasks[task_name]
    rng = np.random.default_rng(seed)               # the set-ups: the same for every policy
    policy_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    rewards: list[float] = []
    steps_taken: list[int] = []
    successes = failures = timeouts = 0
    by_goal: dict[str, dict[str, Any]] = {}
    for _ in range(n_trials):
        obs = task.setup(world, rng)
        total = 0.0
        steps = 0
        ended = False
        outcome = "timeouts"
        first: Goal | None = None               # the goal the trial started with
        while steps < task.max_steps:
            goal = task.goal(world, obs)
            first = first or goal
            obs = world.step(policy(world, obs, goal, policy_rng))
            steps += 1
            if task.is_success(world, obs):
                total += task.success_reward
                successes += 1
                outcome = "successes"
                if task.episodic:
                    ended = True
                    break
                continue
            total += task.step_cost
            if task.is_failure(world, obs):
                failures += 1
                outcome = "failures"
                ended = True
                break
        if not ended:
            timeouts += 1
        rewards.append(total)
        steps_taken.append(steps)
        key = "none" if first is None else f"{first.variable}={first.value}"
        g = by_goal.setdefault(key, {
            "trials": 0, "successes": 0, "failures": 0, "timeouts": 0, "reward": 0.0})
        g["trials"] += 1
        g[outcome] += 1
        g["reward"] += total
    return {
        "task": task_name,
        "world": world.name,
        "n_trials": n_trials,
        "mean_reward": float(np.mean(rewards)) if rewards else 0.0,
        "std_reward": float(np.std(rewards)) if rewards else 0.0,
        "rewards": rewards,
        "successes": successes,
        "failures": failures,
        "timeouts": timeouts,
        "mean_steps": float(np.mean(steps_taken)) if steps_taken else 0.0,
        "by_goal": {k: {"trials": g["trials"], "successes": g["successes"],
                        "failures": g["failures"], "timeouts": g["timeouts"],
                        "mean_reward": g["reward"] / g["trials"]}
                    for k, g in sorted(by_goal.items())},
    }


def run_random_trials(world: World, task_name: str, n_trials: int, seed: int) -> dict[str, Any]:
    """The random-motor baseline of a task (see the module docstring)."""
    task = world.tasks.get(task_name)
    if task is None:
        raise ValueError(no_task(world.name, task_name, world.tasks))
    return run_trials(world, task_name, n_trials, seed, _random_policy(task))
