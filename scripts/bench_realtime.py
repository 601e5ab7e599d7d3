#!/usr/bin/env python3
"""Never stalled: the realtime clock at 100 Hz on core while DBN and landmark batches run.

Runs the actor placements with the realtime clock (the world ticks at --hz; knowledge deltas
apply when they arrive) long enough for DBN and landmark batches to happen, and prints late
ticks (motor not back by the next tick), missed ticks (a tick more than one period late) and
the lateness of the ticks (p50, p99, max). Target (issue 10): 0 missed ticks and p99 < 1 ms
with ``embedded`` and ``processes``.

Before each placement it prints the machine's own lateness: a bare trio loop ticking at the
same rate with the world's clock (:func:`~qlap_runtime.runtime.clock.sleep_until_precisely`)
and nothing else to do, and the load average. On a shared machine that floor, not the actors,
often decides p99.

Usage: scripts/bench_realtime.py [--world core] [--steps 6000] [--hz 100] [--placement P]
                                 [--groups two|each] [--runs N] [--reference-ticks 1000]
"""

from __future__ import annotations

import argparse
import os
import sys
from functools import partial
from pathlib import Path

# This tree's code, not the installed package's (a worktree measures itself).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def lateness_ms(late: list[float], period: float) -> dict[str, float]:
    ms = sorted(x * 1e3 for x in late)
    return {"p50": ms[len(ms) // 2], "p99": ms[min(len(ms) - 1, int(len(ms) * 0.99))],
            "max": ms[-1], "missed": sum(x > period for x in late)}


def reference(hz: float, ticks: int) -> dict[str, float]:
    """The lateness of a bare trio loop that only waits for its ticks (the machine's floor)."""
    import trio

    from qlap_runtime.runtime.clock import sleep_until_precisely

    async def loop() -> list[float]:
        t0, late = trio.current_time(), []
        for i in range(1, ticks + 1):
            deadline = t0 + i / hz
            await sleep_until_precisely(deadline)
            late.append(trio.current_time() - deadline)
        return late

    return lateness_ms(trio.run(loop), 1.0 / hz)


def main() -> None:
    from qlap_runtime.placements.launcher import run_embedded, run_processes
    from qlap_runtime.qlap import Params
    from qlap_runtime.runtime.context import RunContext

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default="core")
    ap.add_argument("--steps", type=int, default=6000,
                    help="ticks (default 6000: DBN batches at 2000 and 4000, a landmark "
                         "batch at 4000)")
    ap.add_argument("--hz", type=float, default=100.0)
    ap.add_argument("--placement", action="append", choices=("embedded", "processes"),
                    help="only this placement (repeatable; default: both)")
    ap.add_argument("--runs", type=int, default=1, help="runs of each placement")
    ap.add_argument("--groups", default="two",
                    help="the processes placement's layout (two: the default groups; each: "
                         "one process per actor)")
    ap.add_argument("--reference-ticks", type=int, default=1000,
                    help="ticks of the bare reference loop before each run (0: none)")
    args = ap.parse_args()
    params = Params()
    print(f"{args.world}, {args.steps} ticks at {args.hz:g} Hz, realtime clock:")
    placements = {"embedded": run_embedded,
                  "processes": partial(run_processes, groups=args.groups)}
    for run in range(args.runs):
        for name in args.placement or list(placements):
            load = " ".join(f"{x:.2f}" for x in os.getloadavg())
            if args.reference_ticks:
                r = reference(args.hz, args.reference_ticks)
                print(f"  machine    load {load}; a bare loop's lateness p50 {r['p50']:.3f} "
                      f"ms, p99 {r['p99']:.3f} ms, max {r['max']:.3f} ms, "
                      f"{r['missed']} ticks more than a period late "
                      f"(of {args.reference_ticks})", flush=True)
            ctx = RunContext(f"rt-{name}-{run}", args.world, args.steps, 0, params,
                             clock="realtime", hz=args.hz)
            s = placements[name](ctx)
            batches = sum(a.get("batches", 0) for a in s["actors"].values())
            world = s["actors"].get("world", {})
            where = "; ".join(f"step {t}: woke {late} ms late, back after {work} ms"
                              for t, late, work in s.get("missed_at") or [])
            print(f"  {name:10s} late ticks {s.get('late_ticks')}, missed ticks "
                  f"{s.get('missed_ticks')}{f' ({where})' if where else ''}, lateness p50 "
                  f"{s.get('lateness_p50_ms')} ms, p99 "
                  f"{s.get('lateness_p99_ms')} ms, max {s.get('lateness_max_ms')} ms "
                  f"({batches} batches computed; full garbage collections at the end "
                  f"{world.get('full_collections')}, {world.get('gc_collected')} objects freed)",
                  flush=True)


if __name__ == "__main__":
    main()
