"""The ``qlap eval`` command: a checkpoint (or the random policy) evaluated on a task
with the protocol of §7.2, its ``--trace`` checked before any trial runs, the result printed as
a line or as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .common import file_problem, make_world, world_mismatch


def _trace_problem(path: Path, policy: str) -> str | None:
    """Why ``qlap eval --trace path`` cannot be written, before any trial runs; None if it can."""
    if policy != "qlap":
        return "a trace needs --policy qlap"
    problem = file_problem(path)
    if problem is None and path.exists():
        problem = "exists: give a new file (a trace is never overwritten)"
    return problem


def cmd_eval(args: argparse.Namespace) -> int:
    from ..agent_run import evaluate
    from ..qlap.checkpoint import CheckpointError

    if args.policy == "qlap" and args.checkpoint is None:
        print("qlap eval: --checkpoint is required with --policy qlap", file=sys.stderr)
        return 2
    if args.trace is not None:
        problem = _trace_problem(args.trace, args.policy)
        if problem is not None:
            print(f"qlap eval: --trace {args.trace}: {problem}", file=sys.stderr)
            return 2
    if args.world is None:            # the world the checkpoint was learned in
        from ..analysis.runs import recorded_world

        recorded = recorded_world(args.checkpoint) if args.checkpoint is not None else None
        args.world = recorded or "core"
    world = make_world(args.world, "eval")
    if world is None:
        return 2
    if args.policy == "qlap":
        mismatch = world_mismatch(args.checkpoint, world, args.world)
        if mismatch is not None:
            print(f"qlap eval: {mismatch}", file=sys.stderr)
            world.close()
            return 2
    try:
        res = evaluate(args.checkpoint, world, args.task, args.trials, args.seed, args.policy,
                       pursue=args.goal, trace=args.trace)
    except (CheckpointError, ValueError, KeyError) as exc:
        reason = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"qlap eval: {reason}", file=sys.stderr)
        return 2
    except OSError as exc:                       # the trace could not be written
        print(f"qlap eval: --trace {args.trace}: cannot write ({exc.strerror or exc})",
              file=sys.stderr)
        return 1
    finally:
        world.close()
    if args.json:
        print(json.dumps(res))
    else:
        pursued = f", pursuing {res['pursued']}" if "pursued" in res else ""
        print(f"{res['world']} {res['task']} ({res['policy']}{pursued}, "
              f"{res['n_trials']} trial{'' if res['n_trials'] == 1 else 's'}): "
              f"mean reward {res['mean_reward']:.3f} ± {res['stderr_reward']:.3f} (s.e.), "
              f"success rate {res['success_rate']:.2f}")
        if "waiting_steps" in res:
            print(f"  a plan waited with the motors held in {res['waiting_steps']:,} of "
                  f"{res['policy_steps']:,} steps; trace: {args.trace}")
        if res.get("steps_without_plan") and (res["steps_without_plan"]
                                              + res.get("steps_goal_held", 0)
                                              == res["policy_steps"]):
            goal = res.get("pursued", "the task's goal")
            print(f"  note: the agent had no plan for {goal} in any step: it moved randomly "
                  f"(or held still) in every trial, as a random policy would")
        elif res.get("steps_without_plan"):
            print(f"  without a plan for the goal: {res['steps_without_plan']:,} of "
                  f"{res['policy_steps']:,} steps (moving randomly meanwhile)")
        if res.get("steps_goal_held") and "pursued" in res:
            print(f"  {res['pursued']} already held in {res['steps_goal_held']:,} of "
                  f"{res['policy_steps']:,} steps (nothing to do there)")
        goals = res.get("by_goal", {})
        if len(goals) > 1:              # a task that draws its goal: each goal's trials
            for name, g in goals.items():
                trials = "trial " if g["trials"] == 1 else "trials"
                print(f"  {name:12s} {g['trials']:4d} {trials}: mean reward "
                      f"{g['mean_reward']:.3f}, {g['successes']} reached, {g['failures']} "
                      f"ended early, {g['timeouts']} timed out")
    return 0
