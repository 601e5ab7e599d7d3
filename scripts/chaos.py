#!/usr/bin/env python3
"""Chaos trials of the processes placement (issue 13): each trial runs core2d with K SIGKILLs
to random restartable actors at random steps — half of them right after the victim's snapshot,
the others at a random step of the world — and, with ``--drop``/``--delay``, messages of the
lockstep topics dropped or delayed on the way (``RunContext.faults``,
``qlap_runtime/bus/faults.py``: the writer still logs them, so a consumer asks its replay log
again), and checks that the run ends with knowledge byte-identical to the synchronous loop's,
or with a one-line error in bounded time (the watchdog's ``stall_s``, or a restart budget
spent). A trial that neither ends nor errs within ``--limit-s`` is counted as hung (SIGTERM to
the launcher).

    scripts/chaos.py --trials 20 --kills 3 --steps 20000
    scripts/chaos.py --trials 5 --kills 3 --steps 20000 --drop 0.002 --delay 0.002
    scripts/chaos.py --trials 3 --kills 2 --steps 3000       # a few minutes

``--lost`` keeps the dropped messages out of the replay logs too: nothing can recover them, so
every such trial must end with the watchdog's one-line error naming the actor and the step it
waits for (never a hang). Prints one line per trial and a JSON summary.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import worlds
from qlap_runtime import agent_run
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.bus.faults import FAULT_TOPICS, Faults
from qlap_runtime.placements.groups import parse_groups
from qlap_runtime.placements.launcher import run_processes
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.snapshot import latest_snapshot
from qlap_runtime.runtime.supervisor import RESTARTABLE, Supervisor

WORLD = "core2d"


def params_for(steps: int) -> Params:
    """Short runs learn with the fault tests' parameters; long ones with the defaults."""
    if steps <= 5000:
        return Params(babble_steps=steps // 2, dbn_period=500, landmark_period=1000,
                      batch_lag=200, k_fixed=5, min_data_points=15)
    return Params(batch_lag=500)


@dataclass
class Kill:
    victim: str
    at: int
    """World step (or snapshot step, with ``after_snapshot``) from which the kill fires."""
    after_snapshot: bool
    fired_at: int | None = None


@dataclass
class Killer:
    kills: list[Kill]
    log: list[str] = field(default_factory=list)

    def __call__(self, sup: Supervisor) -> None:
        world_step = int(sup.board.slot("world").data[0])
        for k in self.kills:
            if k.fired_at is not None:
                continue
            if k.after_snapshot:
                latest = latest_snapshot(sup.snapshot_dir, k.victim) if sup.snapshot_dir else None
                ready = latest is not None and latest[0] >= k.at
            else:
                ready = world_step >= k.at
            p = sup.process_of(k.victim)
            if ready and p.is_alive():
                os.kill(p.pid, signal.SIGKILL)
                k.fired_at = world_step
                self.log.append(f"{k.victim}@{world_step}"
                                f"{' (after snapshot)' if k.after_snapshot else ''}")
            return                              # one kill per poll, in order


def plan(rng: np.random.Generator, kills: int, steps: int, every: int,
         groups: str = "each") -> list[Kill]:
    victims = sorted(a for g in parse_groups(groups) if RESTARTABLE.issuperset(g) for a in g)
    out = []
    for i in range(kills):
        victim = str(rng.choice(victims))
        after = bool(i % 2 == 0)
        if after:
            at = int(rng.integers(1, max(2, (steps - 300) // every))) * every - 1
        else:
            at = int(rng.integers(every, max(every + 1, steps - 300)))
        out.append(Kill(victim, at, after))
    return sorted(out, key=lambda k: k.at)


def sync_knowledge(steps: int, seed: int, params: Params) -> str:
    return agent_run.sync_knowledge(WORLD, steps, seed, params)


def trial(i: int, args: argparse.Namespace) -> dict:
    seed = args.seed + i
    rng = np.random.default_rng(seed)
    params = params_for(args.steps)
    expected = sync_knowledge(args.steps, seed, params)
    killer = Killer(plan(rng, args.kills, args.steps, args.snapshot_every, args.groups))
    with tempfile.TemporaryDirectory(prefix="qlap-chaos-") as tmp:
        w = worlds.make(WORLD)
        faults = None
        if args.drop or args.delay:
            faults = Faults(args.drop, args.delay, args.delay_s,
                            tuple(args.fault_topics.split(",")), seed, args.lost).to_json()
        ctx = RunContext(f"chaos-{i}", WORLD, args.steps, seed, params_for_world(w, params),
                         out=Path(tmp), snapshot_every=args.snapshot_every,
                         stall_s=args.stall_s, faults=faults)
        w.close()
        timer = threading.Timer(args.limit_s, lambda: os.kill(os.getpid(), signal.SIGTERM))
        timer.start()
        t0 = time.monotonic()
        outcome, detail = "", ""
        try:
            summary = run_processes(ctx, on_poll=killer, groups=args.groups)
            got = (Path(tmp) / "knowledge.json").read_text()
            outcome = "identical" if got == expected else "different"
            detail = f"restarts {summary['restarts']}"
            if faults is not None:
                actors = summary["actors"].values()
                dropped = sum(a.get("injected", {}).get("dropped", 0) for a in actors)
                delayed = sum(a.get("injected", {}).get("delayed", 0) for a in actors)
                detail += f"; dropped {dropped}, delayed {delayed} messages"
        except KeyboardInterrupt:
            outcome, detail = "hung", f"no end within {args.limit_s:.0f} s"
        except Exception as exc:                    # the run's one-line error
            outcome, detail = "error", " ".join(str(exc).split())[:300]
        finally:
            timer.cancel()
        wall = time.monotonic() - t0
    return {"trial": i, "seed": seed, "outcome": outcome, "detail": detail,
            "kills": killer.log, "wall_s": round(wall, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--trials", type=int, default=3)
    p.add_argument("--kills", type=int, default=2)
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--seed", type=int, default=100)
    p.add_argument("--snapshot-every", type=int, default=500)
    p.add_argument("--stall-s", type=float, default=30.0)
    p.add_argument("--limit-s", type=float, default=900.0,
                   help="a trial still running after this is counted as hung")
    p.add_argument("--drop", type=float, default=0.0,
                   help="probability that a message of --fault-topics is dropped")
    p.add_argument("--delay", type=float, default=0.0,
                   help="probability that such a message is delayed by --delay-s")
    p.add_argument("--delay-s", type=float, default=0.2)
    p.add_argument("--fault-topics", default=",".join(FAULT_TOPICS),
                   help="comma-separated topics the faults hit (default: every lockstep "
                        "topic)")
    p.add_argument("--groups", default="each",
                   help="the processes placement's layout (each: every actor in a process of "
                        "its own, so each victim restarts alone; two: a victim's group, the "
                        "learners, restarts together, and chain actors are not killed)")
    p.add_argument("--lost", action="store_true",
                   help="dropped messages are missing from the replay logs too (only the "
                        "watchdog's error can end such a trial)")
    args = p.parse_args(argv)
    results = []
    for i in range(args.trials):
        r = trial(i, args)
        results.append(r)
        print(f"trial {i} (seed {r['seed']}): {r['outcome']} in {r['wall_s']} s; kills "
              f"{', '.join(r['kills']) or 'none'}; {r['detail']}", flush=True)
    counts = {k: sum(r["outcome"] == k for r in results)
              for k in ("identical", "different", "error", "hung")}
    print(json.dumps({"trials": args.trials, "kills": args.kills, "steps": args.steps,
                      "drop": args.drop, "delay": args.delay, **counts}))
    return 0 if counts["different"] == 0 and counts["hung"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
