#!/usr/bin/env python3
"""Benchmark of the synchronous agent loop (Algorithm 2) with all learning on.

Runs the agent in a world (default: core) and prints agent steps per second overall, during
motor babbling and during practice (IAC, plans, call list), the time spent in batches, and what
was learned. Budget (docs/architecture.md §4): ≥ 2,000 steps/s overall on core; aim for 5,000.

Usage: scripts/bench_agent.py [--world core] [--steps 30000] [--babble-steps 20000] [--seed 0]
       scripts/bench_agent.py --resume runs/results/core-s1/checkpoints/step-0200000 \
           --steps 4000 [--profile 30]

``--resume`` steps a grown agent loaded from a checkpoint (its world is reset with ``--seed``)
and prints its steps/s; ``--profile N`` prints the N functions with the most own time
(cProfile).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import re
import time

import worlds
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.agent import Agent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default="core")
    ap.add_argument("--steps", type=int, default=30_000)
    ap.add_argument("--babble-steps", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resume", metavar="CHECKPOINT", help="step a grown agent from here")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="with --resume: print the top N functions by own time")
    args = ap.parse_args()
    if args.resume:
        resume(args)
        return
    world = worlds.make(args.world)
    params = params_for_world(world, Params(babble_steps=args.babble_steps))
    agent = Agent(world.variables, params, seed=args.seed)
    obs = world.reset(seed=args.seed)
    period = params.dbn_period
    t_babble = t_practice = t_batch = 0.0
    n_babble = n_practice = 0
    start = time.perf_counter()
    for t in range(args.steps):
        t0 = time.perf_counter()
        motor = agent.step(t, obs, discontinuity=bool(getattr(world, "discontinuity", False)))
        obs = world.step(motor)
        dt = time.perf_counter() - t0
        if t > 0 and t % period == 0:
            t_batch += dt
        elif t < params.babble_steps:
            t_babble += dt
            n_babble += 1
        else:
            t_practice += dt
            n_practice += 1
    wall = time.perf_counter() - start
    world.close()
    print(f"{args.world}: {args.steps} steps in {wall:.1f} s = {args.steps / wall:,.0f} steps/s "
          "overall (world included)")
    if n_babble:
        print(f"  babbling steps : {n_babble / t_babble:,.0f} steps/s")
    if n_practice:
        print(f"  practice steps : {n_practice / t_practice:,.0f} steps/s")
    n_batches = (args.steps - 1) // period
    print(f"  batches        : {n_batches} taking {t_batch:.1f} s "
          f"({t_batch / max(1, n_batches) * 1e3:.0f} ms each on average)")
    c = agent.counters
    print(f"  learned: {len(agent.learner.dbns)} DBNs, {len(agent.plans)} plans, "
          f"{sum(len(s.landmarks) for s in agent.learner.perception.spaces)} landmarks; "
          f"{c.practice_calls} practice calls ({c.successes} succeeded)")


def resume(args: argparse.Namespace) -> None:
    """Steps/s of an agent resumed from a checkpoint (a grown agent: many plans and DBNs)."""
    from qlap_runtime.qlap.checkpoint import load_agent

    agent = load_agent(args.resume)
    m = re.search(r"step-(\d+)", str(args.resume))
    t0 = int(m.group(1)) if m else int(getattr(agent, "step_count", -1)) + 1
    world = worlds.make(args.world)
    obs = world.reset(seed=args.seed)
    prof = cProfile.Profile() if args.profile else None
    start = time.perf_counter()
    if prof:
        prof.enable()
    for t in range(t0, t0 + args.steps):
        motor = agent.step(t, obs, discontinuity=bool(getattr(world, "discontinuity", False)))
        obs = world.step(motor)
    if prof:
        prof.disable()
    wall = time.perf_counter() - start
    world.close()
    print(f"{args.world} resumed at step {t0}: {args.steps} steps in {wall:.1f} s = "
          f"{args.steps / wall:,.0f} steps/s (world included{', profiled' if prof else ''}); "
          f"{len(agent.learner.dbns)} DBNs, {len(agent.plans)} plans")
    if prof:
        pstats.Stats(prof).sort_stats("tottime").print_stats(args.profile)


if __name__ == "__main__":
    main()
