#!/usr/bin/env python3
"""Benchmark of the model learner on a 34-variable stream (the size of the core world, Table 7.1).

Feeds a synthetic stream (4 motors with a force threshold, 28 magnitudes derived from the hand
and a block, 2 nominals) with App. E babbling and prints observe() throughput outside batches and
the time of each batch kind. A second part times one 2000-step batch with 250 DBNs.

With ``--clock cpu`` the process CPU time is measured instead of wall time (steadier on a
shared machine).

Usage: scripts/bench_learner.py [--steps N] [--seed S] [--clock wall|cpu]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from qlap_runtime.qlap import ModelLearner, Params, VariableTable
from qlap_runtime.qlap.babble import Babbler
from qlap_runtime.qlap.dbn import CHANGE
from qlap_runtime.qlap.delta import AddDBN, Delta
from worlds import VariableSpec, VarKind

MOTORS = ("u_x", "u_y", "u_z", "u_UG")
MAGS = ("h_x", "h_y", "h_z", "y_TB", "y_BT", "x_RL", "x_LR", "z_BT", "z_F", "T_L", "T_R",
        "T_T", "c_x", "c_y", *(f"m_{i}" for i in range(14)))
SPECS = [*(VariableSpec(m, VarKind.MOTOR, "a force motor", -1000.0, 1000.0) for m in MOTORS),
         *(VariableSpec(m, VarKind.MAGNITUDE, "a magnitude") for m in MAGS),
         VariableSpec("T", VarKind.NOMINAL, "grasped", values=("false", "true")),
         VariableSpec("bang", VarKind.NOMINAL, "hit the floor", values=("false", "true"))]


class SyntheticCore:
    """Hand moved by thresholded forces; relative variables follow it; a block jitters."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.h = np.zeros(3)
        self.block = np.array([0.0, 1.0, 0.0])
        self.extra = rng.normal(size=14)

    def step(self, u: dict[str, float]) -> None:
        f = np.array([u["u_x"], u["u_y"], u["u_z"]])
        move = np.where(np.abs(f) > 300, np.sign(f) * (np.abs(f) - 300) / 700, 0.0)
        self.h = np.clip(self.h + move, [-2.5, -2, 0], [2.5, 3, 3])
        if self.rng.random() < 0.01:
            self.block[:2] = self.rng.uniform(-2, 2, size=2)
        self.extra += self.rng.normal(scale=0.05, size=14)

    def obs(self) -> dict[str, float]:
        hx, hy, hz = self.h
        bx, by, bz = self.block
        vals = [hx, hy, hz, hy - by - 1, by + 1 - hy, hx - bx - 1, bx + 1 - hx, hz - bz - 1,
                bz, bx + 3, 3 - bx, 3 - by, hx - bx, hy - by, *self.extra]
        out = dict(zip(MAGS, map(float, vals), strict=True))
        out["T"] = float(abs(hx - bx) < 0.5 and abs(hy - by) < 0.5 and hz < 1.2)
        out["bang"] = 0.0
        return out


clock: Callable[[], float] = time.perf_counter


def run_stream(steps: int, seed: int, params: Params) -> tuple[ModelLearner, dict]:
    rng = np.random.default_rng(seed)
    table = VariableTable.from_specs(SPECS)
    learner = ModelLearner(table, params)
    babbler = Babbler(table, params, rng)
    world = SyntheticCore(rng)
    observe_time = 0.0
    observe_steps = 0
    batch_times: dict[str, list[float]] = {"dbn": [], "dbn+landmarks": []}
    for t in range(steps):
        motor, _ = babbler.step()
        obs = world.obs()
        obs.update(motor)
        t0 = clock()
        learner.observe(t, obs)
        dt = clock() - t0
        if t > 0 and t % params.dbn_period == 0:
            kind = "dbn+landmarks" if t % params.landmark_period == 0 else "dbn"
            batch_times[kind].append(dt)
        else:
            observe_time += dt
            observe_steps += 1
        world.step(motor)
    return learner, {"observe_steps_per_s": observe_steps / observe_time,
                     "batches": batch_times}


def bench_250(learner: ModelLearner, step: int) -> float:
    """Time one 2000-step batch after padding the learner to 250 change DBNs."""
    rng = np.random.default_rng(1)
    index = learner.perception.events
    cons = index.event_of_cons
    while sum(d.kind == CHANGE for d in learner.dbns.values()) < 250:
        e1 = index.decode(int(rng.integers(index.n_events)))
        e2 = index.decode(int(cons[rng.integers(len(cons))]))
        if e1.var == e2.var:
            continue
        new_id = learner.next_id
        learner.apply_delta(Delta(0, step, step, (AddDBN(CHANGE, e1, e2),)))
        if learner.next_id == new_id:
            continue                                    # a DBN with these events exists
        dbn = learner.dbns[new_id]
        n = learner.params.stored_activations
        hx, _ = learner.perception.history()
        rows = rng.integers(len(hx), size=n)
        for r in rows:
            dbn.record(hx[r], bool(rng.random() < 0.6), 0)
    t0 = clock()
    learner.compute_batch(step + 2000)
    return clock() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    args = ap.parse_args()
    global clock
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    params = Params()
    t0 = clock()
    learner, res = run_stream(args.steps, args.seed, params)
    wall = clock() - t0
    n_vars = len(learner.table)
    print(f"stream: {args.steps} steps, {len(SPECS)} world variables ({n_vars} qualitative), "
          f"{args.clock} {wall:.2f} s")
    print(f"observe() outside batches: {res['observe_steps_per_s']:,.0f} steps/s")
    for kind, ts in res["batches"].items():
        if ts:
            print(f"batch {kind:14s}: n={len(ts)} mean {np.mean(ts)*1e3:.1f} ms "
                  f"max {np.max(ts)*1e3:.1f} ms")
    k = learner.knowledge()
    n_lm = sum(len(v) for v in k["landmarks"].values())
    print(f"learned: k={k['k']}, {len(k['dbns'])} DBNs, {n_lm} landmarks")
    small, _ = run_stream(4000, args.seed, params)
    dt_small = bench_250(small, 4000)           # the batch at step 6000: lines 6–9 only
    n_small = sum(d.kind == CHANGE for d in small.dbns.values())
    print(f"2000-step batch with {n_small} change DBNs: {dt_small*1e3:.0f} ms")
    dt = bench_250(learner, args.steps)
    n = sum(d.kind == CHANGE for d in learner.dbns.values())
    print(f"2000-step batch with {n} change DBNs: {dt*1e3:.0f} ms")


if __name__ == "__main__":
    main()
