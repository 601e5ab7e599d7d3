#!/usr/bin/env python3
"""Never stalled: the realtime clock at 100 Hz on core while landmark batches run.

Runs the actor placements with the realtime clock (the world ticks at --hz; knowledge deltas
apply when they arrive) long enough for DBN and landmark batches to happen, and prints late
ticks (motor not back by the next tick), missed ticks (a tick more than one period late) and
the lateness of the ticks (p50, p99, max). Target (issue 5): 0 missed ticks and p99 < 2 ms with
``processes``.

Usage: scripts/bench_realtime.py [--world core] [--steps 4500] [--hz 100]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

# This tree's code, not the installed package's (a worktree measures itself).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    from qlap_runtime.placements.launcher import run_embedded, run_processes
    from qlap_runtime.qlap import Params
    from qlap_runtime.runtime.context import RunContext

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default="core")
    ap.add_argument("--steps", type=int, default=4500,
                    help="ticks (default 4500: DBN batches at 2000, 4000 and a landmark batch "
                         "at 4000)")
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--placement", action="append", choices=("embedded", "processes"),
                    help="only this placement (repeatable; default: both)")
    args = ap.parse_args()
    params = Params()
    print(f"{args.world}, {args.steps} ticks at {args.hz:g} Hz, realtime clock:")
    placements = {"embedded": run_embedded, "processes": run_processes}
    for name in args.placement or list(placements):
        fn = placements[name]
        ctx = RunContext(f"rt-{name}", args.world, args.steps, 0, params,
                         clock="realtime", hz=args.hz)
        s = fn(ctx)
        batches = sum(a.get("batches", 0) for a in s["actors"].values())
        print(f"  {name:10s} late ticks {s.get('late_ticks')}, missed ticks "
              f"{s.get('missed_ticks')}, lateness p50 {s.get('lateness_p50_ms')} ms, p99 "
              f"{s.get('lateness_p99_ms')} ms, max {s.get('lateness_max_ms')} ms "
              f"({batches} batches computed)")


if __name__ == "__main__":
    main()
