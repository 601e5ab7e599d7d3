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

``--against TREE`` (with ``--resume``) measures side by side: ``--rounds`` alternating runs of
this code and of the source tree TREE (e.g. a ``git worktree`` of main), each in a fresh process
on the same checkpoint and world seed, then prints the speed ratio (this / TREE, from the
median CPU times of the step loop: process CPU time is far less disturbed than wall time by
other work on the machine) and whether both ended with byte-identical knowledge and Q-tables:

    scripts/bench_agent.py --resume CKPT --steps 8000 --against /path/to/other/checkout --rounds 3
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import json
import os
import pstats
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

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
    ap.add_argument("--against", metavar="TREE",
                    help="with --resume: compare with the code of source tree TREE, side by side")
    ap.add_argument("--rounds", type=int, default=3, help="with --against: runs of each")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)  # child of --against
    args = ap.parse_args()
    if args.resume and args.against:
        compare(args)
        return
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


def digest(agent: Agent) -> str:
    """SHA-256 of what the agent knows: knowledge.json's content and every plan's Q-table and
    Sarsa traces (the bytes an optimisation must leave unchanged)."""
    h = hashlib.sha256(json.dumps(agent.knowledge(), sort_keys=True).encode())
    for pid in sorted(agent.plans):
        plan = agent.plans[pid]
        h.update(f"plan {pid}".encode())
        for arr in (plan.q, getattr(plan.sarsa, "e", None)):
            if arr is not None:
                h.update(repr(arr.shape).encode() + arr.tobytes())
    return h.hexdigest()


def compare(args: argparse.Namespace) -> None:
    """Alternate runs of this code and of ``args.against``; print the ratio and the digests."""
    here = Path(__file__).resolve().parents[1]
    trees = {"this": here, "ref": Path(args.against).resolve()}
    times: dict[str, list[float]] = {k: [] for k in trees}
    digests: dict[str, set[str]] = {k: set() for k in trees}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--resume", str(args.resume),
           "--steps", str(args.steps), "--seed", str(args.seed), "--world", args.world, "--json"]
    for r in range(args.rounds):
        for name, tree in trees.items():
            env = {**os.environ, "PYTHONPATH": str(tree)}
            out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
            res = json.loads(out.stdout.strip().splitlines()[-1])
            if Path(res["module"]).resolve().parents[1] != tree:
                raise SystemExit(f"{name}: imported qlap_runtime from {res['module']}, not {tree}")
            times[name].append(res["cpu"])
            digests[name].add(res["digest"])
            print(f"  round {r + 1} {name:4s} ({tree}): {args.steps / res['cpu']:,.0f} steps "
                  f"per CPU second ({args.steps / res['wall']:,.0f} per wall second)")
    t_this, t_ref = statistics.median(times["this"]), statistics.median(times["ref"])
    same = len(digests["this"] | digests["ref"]) == 1
    print(f"{args.world} resumed from {args.resume}, {args.steps} steps, median of {args.rounds}: "
          f"this {args.steps / t_this:,.0f}, ref {args.steps / t_ref:,.0f} steps per CPU second, "
          f"ratio {t_ref / t_this:.3f}; knowledge and Q-tables "
          f"{'byte-identical' if same else 'DIFFER'} ({', '.join(sorted(digests['this']))[:16]})")
    if not same:
        raise SystemExit(1)


def resume(args: argparse.Namespace) -> None:
    """Steps/s of an agent resumed from a checkpoint (a grown agent: many plans and DBNs)."""
    from qlap_runtime.qlap.checkpoint import load_agent

    agent = load_agent(args.resume)
    m = re.search(r"step-(\d+)", str(args.resume))
    t0 = int(m.group(1)) if m else int(getattr(agent, "step_count", -1)) + 1
    world = worlds.make(args.world)
    obs = world.reset(seed=args.seed)
    # CPU time: on a busy machine wall-clock profiles charge functions for time not running.
    prof = cProfile.Profile(time.process_time) if args.profile else None
    start, cpu0 = time.perf_counter(), time.process_time()
    if prof:
        prof.enable()
    for t in range(t0, t0 + args.steps):
        motor = agent.step(t, obs, discontinuity=bool(getattr(world, "discontinuity", False)))
        obs = world.step(motor)
    if prof:
        prof.disable()
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu0
    world.close()
    if args.json:
        import qlap_runtime
        print(json.dumps({"wall": wall, "cpu": cpu, "digest": digest(agent),
                          "module": qlap_runtime.__file__}))
        return
    print(f"{args.world} resumed at step {t0}: {args.steps} steps in {wall:.1f} s = "
          f"{args.steps / wall:,.0f} steps/s (world included{', profiled' if prof else ''}); "
          f"{len(agent.learner.dbns)} DBNs, {len(agent.plans)} plans")
    if prof:
        pstats.Stats(prof).sort_stats("tottime").print_stats(args.profile)


if __name__ == "__main__":
    main()
