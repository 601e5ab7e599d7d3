#!/usr/bin/env python3
"""Regression net for the model learner: the knowledge of three fixed runs, byte for byte.

Runs (a) the toy world's babble stream (tests/qlap/toyworld.py), (b) bench_learner.py's synthetic
34-variable stream and (c) the MuJoCo ``core`` world with App. E babbling (the learner observes
obs(t) plus the motor values applied since t − 1), and writes
``json.dumps(learner.knowledge(), sort_keys=True)`` of each to ``OUT/<name>.json``. With
``--compare REF`` each output must be byte-identical to ``REF/<name>.json``.

Usage: scripts/regress_learner.py OUT [--compare REF] [--only toy,synthetic,core]
       [--steps-toy N] [--steps-synthetic N] [--steps-core N] [--profile FILE]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from qlap_runtime.qlap import ModelLearner, Params, VariableTable  # noqa: E402
from qlap_runtime.qlap.babble import Babbler  # noqa: E402
from qlap_runtime.qlap.checkpoint import atomic_write_bytes  # noqa: E402
from qlap_runtime.qlap.variables import Kind  # noqa: E402


def run_toy(steps: int) -> ModelLearner:
    from tests.qlap.toyworld import SPECS, babble_stream

    learner = ModelLearner(VariableTable.from_specs(SPECS), Params())
    for t, obs in babble_stream(steps, 0):
        learner.observe(t, obs)
    return learner


def run_synthetic(steps: int) -> ModelLearner:
    from bench_learner import run_stream

    learner, _ = run_stream(steps, 0, Params())
    return learner


def run_core(steps: int) -> ModelLearner:
    import worlds

    world = worlds.make("core")
    params = Params()
    table = VariableTable.from_specs(world.variables)
    learner = ModelLearner(table, params)
    babbler = Babbler(table, params, np.random.default_rng(0))
    obs = world.reset(seed=0)
    motor = {m.name: 0.0 for m in table.of_kind(Kind.MOTOR)}
    for t in range(steps):
        full = dict(obs)
        full.update(motor)                 # the motor values applied in the previous step
        learner.observe(t, full)
        motor, _ = babbler.step()
        obs = world.step(motor)
    world.close()
    return learner


RUNS = {"toy": run_toy, "synthetic": run_synthetic, "core": run_core}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--compare", type=Path)
    ap.add_argument("--only", default="toy,synthetic,core")
    ap.add_argument("--steps-toy", type=int, default=20_000)
    ap.add_argument("--steps-synthetic", type=int, default=20_000)
    ap.add_argument("--steps-core", type=int, default=30_000)
    ap.add_argument("--profile", type=Path, help="cProfile the runs into this file")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    steps = {"toy": args.steps_toy, "synthetic": args.steps_synthetic, "core": args.steps_core}
    failed = False
    prof = cProfile.Profile() if args.profile else None
    for name in args.only.split(","):
        t0, c0 = time.perf_counter(), time.process_time()
        if prof:
            prof.enable()
        learner = RUNS[name](steps[name])
        if prof:
            prof.disable()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        text = json.dumps(learner.knowledge(), sort_keys=True)
        atomic_write_bytes(args.out / f"{name}.json", text.encode())
        status = ""
        if args.compare is not None:
            ref = (args.compare / f"{name}.json").read_text()
            same = ref == text
            failed |= not same
            status = "IDENTICAL" if same else "DIFFERENT"
        print(f"{name:10s} {steps[name]:6d} steps  wall {wall:7.2f} s  cpu {cpu:7.2f} s  "
              f"{len(learner.dbns):5d} DBNs  {status}", flush=True)
    if prof:
        prof.dump_stats(str(args.profile))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
