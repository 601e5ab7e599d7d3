#!/usr/bin/env python
"""Agent steps per second of each registered world under a random motor policy.

Physics substeps included; the random motor values are drawn beforehand so that only the
world's ``step`` is timed. Usage: ``python scripts/bench_worlds.py [--steps N] [SPEC ...]``.
Target (docs/architecture.md §4): at least 10,000 agent steps/s for ``core``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from worlds import make, registered
from worlds.check import random_motor


def bench(spec: str, steps: int, seed: int = 0) -> float:
    world = make(spec)
    try:
        rng = np.random.default_rng(seed)
        motors = [random_motor(world, rng) for _ in range(steps)]
        world.reset(seed=seed)
        step = world.step
        start = time.perf_counter()
        for motor in motors:
            step(motor)
        return steps / (time.perf_counter() - start)
    finally:
        world.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("specs", nargs="*", help="world specs (default: every registered one)")
    parser.add_argument("--steps", type=int, default=20_000)
    args = parser.parse_args(argv)
    for spec in args.specs or registered():
        rate = bench(spec, args.steps)
        print(f"{spec:30s} {rate:10,.0f} agent steps/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
