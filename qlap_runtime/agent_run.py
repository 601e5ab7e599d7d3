"""Headless runs of the synchronous agent (Algorithm 2) in a world, and evaluation trials.

``run_agent`` is the main job: an agent learning autonomously in a world for N steps, with
checkpoints every 10,000 steps (§7.2), a metrics log every 1,000 steps, ``knowledge.json`` and
``summary.json`` (schemas in docs/outputs.md). ``evaluate`` runs the §7.2 protocol on a
checkpoint: goal mode, learning off, −0.01 a step, +9.99 on success, 300 steps.
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import WorldFailed
from .metrics import METRICS_EVERY, METRICS_FILE, MetricsLog, Rejections, summary_of
from .qlap import Params
from .qlap.agent import Agent
from .qlap.checkpoint import (
    atomic_write_json,
    load_agent,
    save_final_checkpoint,
    world_state_of,
)
from .qlap.perception import InvalidObservation
from .runtime.background import CheckpointWriter

ProgressFn = Callable[[int, Agent], None]


def params_for_world(world: Any, base: Params | None = None) -> Params:
    """Apply the options a world declares for the agent (e.g. pong's k = 6 and NRP, §7.10.1)."""
    params = base or Params()
    opts = dict(getattr(world, "agent_options", {}) or {})
    changes: dict[str, Any] = {}
    if "k_fixed" in opts:
        changes["k_fixed"] = int(opts["k_fixed"])
    if opts.get("nrp"):
        changes["ablations"] = dataclasses.replace(params.ablations, nrp=True)
    if "derivative_zero_band" in opts:
        changes["derivative_zero_band"] = float(opts["derivative_zero_band"])
    step_seconds = getattr(world, "step_seconds", None)
    if step_seconds is not None and float(step_seconds) != params.step_seconds:
        changes["step_seconds"] = float(step_seconds)
    return params.replace(**changes) if changes else params


def run_agent(world: Any, steps: int, seed: int, out: Path | None = None,
              params: Params | None = None, progress: ProgressFn | None = None,
              checkpoint_every: int = 10_000, agent: Agent | None = None,
              keep_checkpoints: int | None = None, metrics_every: int = METRICS_EVERY,
              on_metrics: Callable[[dict[str, Any]], None] | None = None,
              restored: bool = False,
              stop: threading.Event | None = None) -> tuple[Agent, dict[str, Any]]:
    """Run the agent autonomously in ``world`` for ``steps`` steps.

    With ``out``: ``checkpoints/step-NNNNNNN`` every ``checkpoint_every`` steps (the newest
    ``keep_checkpoints`` kept; None: all, 0: none), ``metrics.jsonl`` every ``metrics_every``
    steps, and at the end ``knowledge.json``, ``summary.json`` and ``checkpoints/final`` (a
    link to the last ``step-N`` when that is the final state). ``on_metrics`` receives each
    metrics line (written or not).

    An observation the agent rejects (NaN, unknown variable) is counted and logged in the
    summary, and the agent keeps its previous motor command; the run goes on. A world whose
    ``step`` raises stops the run: the outputs of the steps done are written, then
    :class:`WorldFailed` is raised.

    Checkpoints carry the world's state (``world.json``,
    :func:`~.qlap.checkpoint.world_state_of`); a copy of the agent is written in a thread of
    its own while the loop goes on (``runtime.background.CheckpointWriter``, docs/decisions.md
    107). ``restored``: the world was set to a
    checkpoint's state (``restore_world``) and continues from it instead of ``reset(seed)``:
    with the checkpoint's agent the run is then the uninterrupted one's. ``stop`` (set by a
    signal handler: Ctrl-C, SIGTERM) ends the run between two steps, its outputs written as
    after the last step; the summary's ``interrupted_at`` names the first step not run.
    """
    params = params_for_world(world, params)
    agent = agent or Agent(world.variables, params, seed=seed)
    obs = world.observe() if restored else world.reset(seed=seed)
    motor = dict(agent.motor)
    rejected = Rejections()
    world_spec = getattr(world, "spec", None) or getattr(world, "name", None)
    start = agent.step_count + 1
    ckpts = Path(out) / "checkpoints" if out is not None else None
    metrics = MetricsLog(Path(out) / METRICS_FILE if out is not None else None, agent,
                         start=start, every=metrics_every, on_line=on_metrics) \
        if out is not None or on_metrics is not None else None
    last_saved: tuple[int, Path | None] = (-1, None)
    writer = CheckpointWriter()
    failed: WorldFailed | None = None
    done = steps
    t0 = time.perf_counter()
    interrupted: int | None = None
    try:
        for t in range(start, start + steps):
            if stop is not None and stop.is_set():
                interrupted, done = t, t - start
                break
            try:
                motor = agent.step(t, obs,
                                   discontinuity=bool(getattr(world, "discontinuity", False)))
            except InvalidObservation as exc:
                rejected.add(f"step {t}: {exc}")
            try:
                obs = world.step(motor)
            except Exception as exc:        # the world broke: keep what was learned up to t
                failed = WorldFailed(str(world_spec or type(world).__name__), t, exc)
                done = t - start + 1
                break
            if progress is not None:
                progress(t, agent)
            if metrics is not None:
                metrics.after_step(t + 1, agent)
            if ckpts is not None and (t + 1) % checkpoint_every == 0:
                last_saved = (t, writer.save(agent, ckpts, t + 1, world_spec, keep_checkpoints,
                                             world_state_of(world),
                                             copy_agent=t + 1 < start + steps))
        writer.wait()                     # a checkpoint's error (a full disk) stops the run here
        wall = time.perf_counter() - t0
        if metrics is not None:
            metrics.finish(start + done, agent)
    except BaseException:
        writer.join()                     # the write in flight ends; the first error is raised
        raise
    finally:
        if metrics is not None:
            metrics.close()
    summary = summary_of(agent, world, seed, done, wall, rejected)
    if failed is not None:
        summary["world_error"] = str(failed)
    if interrupted is not None:
        summary["interrupted_at"] = interrupted
    if out is not None:
        out = Path(out)
        atomic_write_json(out / "knowledge.json", agent.knowledge())
        atomic_write_json(out / "summary.json", summary)
        same = last_saved[1] if last_saved[0] == start + done - 1 else None
        save_final_checkpoint(agent, out / "checkpoints", world_spec, same_as=same,
                              world_state=world_state_of(world) if failed is None else None)
    if failed is not None:
        raise failed
    return agent, summary


def knowledge_json(agent: Agent) -> str:
    """The text of the agent's ``knowledge.json`` (the format of ``atomic_write_json``): what
    every placement's knowledge is compared by."""
    return json.dumps(agent.knowledge(), indent=1, sort_keys=True)


def sync_knowledge(world_spec: str, steps: int, seed: int, params: Params) -> str:
    """The oracle of the actor placements: ``knowledge.json`` of the synchronous loop in a fresh
    ``world_spec`` with the same steps, seed and parameters."""
    import worlds

    world = worlds.make(world_spec)
    try:
        agent, _ = run_agent(world, steps, seed, params=params)
    finally:
        world.close()
    return knowledge_json(agent)


def goal_index(agent: Agent, goal: Any) -> tuple[int, int]:
    """Map a world's Goal (variable name, value label) to the agent's action key."""
    var = agent.table.index(goal.variable)
    return agent.set_goal(var, goal.value)


def goal_policy(agent: Agent, world: Any, task_name: str, pursue: Any = None,
                counts: dict[str, int] | None = None, trace: list[dict[str, Any]] | None = None
                ) -> Callable[[Any, Mapping[str, float], Any, np.random.Generator],
                              Mapping[str, float]]:
    """The agent as a policy for ``worlds.evaluate.run_trials`` (§7.2.1), learning off.

    A trial starts (world step 0) with :meth:`Agent.new_episode` (motors at rest, histories
    broken); the world's own discontinuities (``World.discontinuity``) are passed on; the goal
    is set whenever the task's goal changes. With ``agent.learning`` False nothing the agent
    has learned changes, except that plans' Sarsa(λ) adapts within a trial (§5.2.2) and the
    next trial undoes it (``Params.sarsa_in_trials``; call :meth:`Agent.end_trial` after the
    last trial; tests/qlap/test_agent.py).

    With ``pursue`` (a ``worlds.base.Goal``) the agent pursues that goal in every trial instead
    of the task's, while the task still judges the trial: how well one learned action would do
    the task (``qlap eval --goal``, docs/analysis.md).

    ``counts`` (if given) counts the policy's ``steps``, those in which the goal already held
    (``goal_held``: nothing to do), and those ``without_plan``: the goal did not hold, the agent
    had no plan for it and moved randomly (or held still) instead (§7.2.1).

    ``trace`` (if given) gets one record per step (:func:`trace_record`): what the agent
    was doing, for ``qlap eval --trace``.
    """
    if task_name not in world.tasks:
        from worlds.evaluate import no_task

        raise ValueError(no_task(world.name, task_name, world.tasks))
    task = world.tasks[task_name]
    idle = "zero" if task.hold_motors_at_zero_without_plan else "babble"
    agent.learning = False
    state: dict[str, Any] = {"t": agent.step_count, "goal": None, "trial": -1}

    def qlap_policy(w: Any, obs: Mapping[str, float], goal: Any,
                    rng: np.random.Generator) -> Mapping[str, float]:
        if w.step_count == 0:                           # a new trial
            agent.new_episode()
            state["goal"] = None
            state["trial"] += 1
        if pursue is not None:
            goal = pursue
        if goal != state["goal"]:
            state["goal"] = goal
            agent.set_goal(agent.table.index(goal.variable), goal.value, idle=idle)
        state["t"] += 1
        motor = agent.step(int(state["t"]), obs,
                           discontinuity=bool(getattr(w, "discontinuity", False)))
        if counts is not None:
            held = agent.goal_held()
            counts["steps"] = counts.get("steps", 0) + 1
            counts["goal_held"] = counts.get("goal_held", 0) + held
            counts["without_plan"] = (counts.get("without_plan", 0)
                                      + (agent.mode == "idle" and not held))
        if trace is not None:
            trace.append(trace_record(agent, state["trial"], w.step_count, goal, motor))
        return motor

    return qlap_policy


def trace_record(agent: Agent, trial: int, step: int, goal: Any,
                 motor: Mapping[str, float]) -> dict[str, Any]:
    """One step of an evaluation as ``qlap eval --trace`` writes it (docs/analysis.md): the
    trial and its step, the goal, the agent's mode, its call list (top first), whether the
    deepest plan waits with the motors held (:meth:`Agent.waiting`) and the motor command."""
    return {"trial": trial, "step": step, "goal": f"{goal.variable}={goal.value}",
            "mode": agent.mode, "calls": agent.call_list_labels(), "waiting": agent.waiting(),
            "motor": {k: float(v) for k, v in motor.items()}}


def write_trace(path: str | Path, records: list[dict[str, Any]],
                rewards: list[float]) -> None:
    """Write an evaluation's trace as JSON lines, atomically: the step records, then one
    ``{"trial": i, "reward": r}`` line per trial."""
    from .qlap.checkpoint import atomic_file

    with atomic_file(Path(path)) as f:
        for rec in records:
            f.write(json.dumps(rec, ensure_ascii=False).encode() + b"\n")
        for i, r in enumerate(rewards):
            f.write(json.dumps({"trial": i, "reward": float(r)}).encode() + b"\n")


def evaluate(checkpoint: str | Path, world: Any, task_name: str, trials: int, seed: int,
             policy: str = "qlap", pursue: Any = None,
             trace: str | Path | None = None) -> dict[str, Any]:
    """The §7.2 protocol: ``trials`` trials of a task with the agent in goal mode.

    Learning is off during evaluation, so every trial uses the checkpoint's knowledge
    unchanged (:func:`goal_policy`). A trial in which the agent has no plan for the goal moves
    randomly (or holds the motors at rest when the task says so, §7.9.1). With ``pursue`` (a
    ``worlds.base.Goal``, policy "qlap" only) the agent pursues that goal instead of the
    task's; the result names it as ``pursued`` ("T_L.dot=+"). ``steps_without_plan`` of
    ``policy_steps`` (policy "qlap"): the steps in which the agent had no plan for its goal.
    With ``trace`` (policy "qlap" only) every step is written there (:func:`write_trace`) and
    the result's ``waiting_steps`` counts the steps in which a plan waited (§5.3.1, Alg. 7).
    """
    from worlds.evaluate import run_random_trials, run_trials

    if pursue is not None and policy != "qlap":
        raise ValueError(f"a goal to pursue needs the qlap policy, not {policy!r}")
    if trace is not None and policy != "qlap":
        raise ValueError(f"a trace needs the qlap policy, not {policy!r}")
    if policy == "random":
        res = run_random_trials(world, task_name, trials, seed)
    elif policy == "qlap":
        agent = load_agent(checkpoint)
        if pursue is not None:
            goal_index(agent, pursue)                   # an unknown goal: ValueError, now
            agent.clear_goal()
        counts: dict[str, int] = {}
        records: list[dict[str, Any]] | None = [] if trace is not None else None
        res = run_trials(world, task_name, trials, seed,
                         goal_policy(agent, world, task_name, pursue, counts, records))
        agent.end_trial()                               # the last trial's Sarsa, undone
        if trace is not None and records is not None:
            write_trace(trace, records, res["rewards"])
            res["waiting_steps"] = sum(1 for rec in records if rec["waiting"])
        res["steps_without_plan"] = counts.get("without_plan", 0)
        res["steps_goal_held"] = counts.get("goal_held", 0)
        res["policy_steps"] = counts.get("steps", 0)
        if pursue is not None:
            res["pursued"] = f"{pursue.variable}={pursue.value}"
    else:
        raise ValueError(f"policy must be 'qlap' or 'random', got {policy!r}")
    rewards = np.asarray(res["rewards"], dtype=float)
    res["stderr_reward"] = float(rewards.std(ddof=1) / math.sqrt(len(rewards))) \
        if len(rewards) > 1 else 0.0
    res["success_rate"] = res["successes"] / max(1, res["n_trials"])
    res["policy"] = policy
    return res
