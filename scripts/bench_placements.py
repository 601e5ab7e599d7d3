#!/usr/bin/env python3
"""Lockstep steps per second of each placement beside the synchronous loop, all learning on.

Runs the same world, seed and parameters with the synchronous loop, the embedded actors, the
processes placement in each layout of ``--groups`` (``processes``: the default groups, the step
chain with the planner and the learners; ``processes/each``: one process per actor) and
(``--local``) the terminal UI's local runner, prints steps/s and waits, and checks that they
all learned the same thing. Every run writes the same files (checkpoints every 10,000 steps,
metrics, knowledge); the synchronous loop's time runs to its last step, as a placement's
loop time does.

Usage: scripts/bench_placements.py [--world core] [--steps 6000] [--lag 500] [--babble 3000]
                                   [--groups two,each] [--local] [--only embedded,processes]
                                   [--pairs N]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

# This tree's code, not the installed package's (a worktree measures itself; the processes
# placement's children inherit the path).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] + " " + " ".join(
        __doc__.split("\n\n")[1].split()),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--world", default="core", help="world spec of every run")
    ap.add_argument("--steps", type=int, default=6000,
                    help="agent steps of each run (docs/runtime.md's figures: 30000)")
    ap.add_argument("--lag", type=int, default=500,
                    help="batch lag L of the actor placements and the sync loop alike")
    ap.add_argument("--babble", type=int, default=3000,
                    help="motor-babbling steps before IAC practice (§6.1)")
    ap.add_argument("--seed", type=int, default=0, help="seed of every run")
    ap.add_argument("--groups", default="two,each",
                    help="the processes placement's layouts to run, comma-separated (two: "
                         "the default groups; each: one process per actor; none: skip)")
    ap.add_argument("--local", action="store_true",
                    help="also the terminal UI's local runner (tui/driver.py)")
    ap.add_argument("--only", default="embedded,processes",
                    help="the actor placements to run, comma-separated")
    ap.add_argument("--pairs", type=int, default=1,
                    help="rounds of the synchronous loop and every placement, one after the "
                         "other; each placement's ratio is to its round's sync run, and with "
                         "several rounds the median and range of the ratios close the output "
                         "(a 2-core machine's noise moves one pair by 10-30%%)")
    args = ap.parse_args()
    if args.pairs < 1:
        ap.error(f"--pairs must be at least 1, got {args.pairs}")
    ratios: dict[str, list[float]] = {}
    for round_ in range(args.pairs):
        if args.pairs > 1:
            print(f"round {round_ + 1} of {args.pairs}:")
        for name, ratio in one_round(args).items():
            ratios.setdefault(name, []).append(ratio)
    if args.pairs > 1:
        print(f"wall / sync over {args.pairs} rounds:")
        for name, rs in ratios.items():
            print(f"  {name:15s} median {statistics.median(rs):.2f}  range "
                  f"{min(rs):.2f}-{max(rs):.2f}  ({', '.join(f'{r:.2f}' for r in rs)})")


def one_round(args: argparse.Namespace) -> dict[str, float]:
    """The synchronous loop, then each placement: their wall / sync ratios."""
    import worlds
    from qlap_runtime.agent_run import knowledge_json, params_for_world, run_agent
    from qlap_runtime.placements.launcher import run_embedded, run_processes
    from qlap_runtime.qlap import Params
    from qlap_runtime.runtime.context import RunContext

    only = set(args.only.split(",")) - {""}
    world = worlds.make(args.world)
    params = params_for_world(world, Params(babble_steps=args.babble, batch_lag=args.lag))
    # The synchronous loop writes what every placement writes (checkpoints every 10,000 steps
    # in a thread, metrics), and its time runs to its last step as a placement's loop time
    # does (docs/decisions.md 110).
    last = [0.0, 0.0]

    def at_step(_t: int, _agent: Any) -> None:
        last[0], last[1] = time.perf_counter(), time.thread_time()

    with tempfile.TemporaryDirectory(prefix="bench-sync-") as tmp:
        t0, cpu0 = time.perf_counter(), time.thread_time()
        agent, _ = run_agent(world, args.steps, args.seed, out=Path(tmp), params=params,
                             progress=at_step)
    wall, cpu = last[0] - t0, last[1] - cpu0
    world.close()
    reference = knowledge_json(agent)
    print(f"{args.world}, {args.steps} steps, lag {args.lag}, babbling {args.babble}:")
    sync_wall = wall
    print(f"  {'sync':15s} {args.steps / wall:8,.0f} steps/s  wall {wall:.1f} s  "
          f"CPU {cpu:.2f} s", flush=True)
    ratios: dict[str, float] = {}
    runs: list[tuple[str, Any]] = [("embedded", run_embedded)] if "embedded" in only else []
    layouts = [g for g in args.groups.split(",") if g and g != "none"] \
        if "processes" in only else []
    for layout in layouts:
        label = "processes" if layout == "two" else f"processes/{layout}"
        runs.append((label, partial(run_processes, groups=layout)))
    for name, fn in runs:
        with tempfile.TemporaryDirectory(prefix=f"bench-{name.replace('/', '-')}-") as tmp:
            out = Path(tmp)
            s = fn(RunContext(f"bench-{name.replace('/', '-')}", args.world, args.steps,
                              args.seed, params, out=out))
            same = (out / "knowledge.json").read_text() == reference
        loop_wall = args.steps / s["loop_steps_per_s"]
        ratios[name] = loop_wall / sync_wall
        print(f"  {name:15s} {s['loop_steps_per_s']:8,.0f} steps/s (start-up excluded; "
              f"{s['steps_per_s']:,.0f} with it)  wall / sync {loop_wall / sync_wall:.2f}  "
              f"waits {s['waits']} ({s['actors']['executor'].get('wait_s', 0):.2f} s)  "
              f"chain CPU {s['actors']['world'].get('loop_cpu_s', 0):.2f} s  "
              f"identical knowledge: {same}", flush=True)
    if args.local:
        from tui.driver import LocalDriver

        with tempfile.TemporaryDirectory(prefix="bench-local-") as tmp:
            out = Path(tmp)
            world = worlds.make(args.world)
            d = LocalDriver(world, seed=args.seed, params=params, steps=args.steps, out=out,
                            run_id="bench-local", world_spec=args.world)
            t0 = time.perf_counter()
            d.start()
            while not d.finished and d.alive:
                d.wait(0.05)
            wall = time.perf_counter() - t0
            d.stop()
            world.close()
            same = (out / "knowledge.json").read_text() == reference
        ratios["local"] = wall / sync_wall
        print(f"  {'local':15s} {args.steps / wall:8,.0f} steps/s (start-up included)  "
              f"wall / sync {wall / sync_wall:.2f}  identical knowledge: {same}", flush=True)
    return ratios


if __name__ == "__main__":
    main()
