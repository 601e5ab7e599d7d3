#!/usr/bin/env python3
"""Every experiment of chapter 7 end to end with the --quick preset (a smoke run, minutes).

    nice -n 19 .venv/bin/python scripts/experiments_smoke.py                 # all of them
    .venv/bin/python scripts/experiments_smoke.py --only pong transfer --engine ray

Runs ``qlap experiment NAME --quick --out OUT`` for each experiment in turn (OUT shared, so
the QLAP core runs of core-tasks serve extraneous, dbn-count and ablations), prints each one's
wall time and exit code, and a table at the end; exits 1 when one failed. Resumable like the
command itself: a second invocation reuses everything already computed. docs/experiments.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    from qlap_runtime.experiments.registry import EXPERIMENTS

    p = argparse.ArgumentParser(
        prog="experiments_smoke.py",
        description="Run every experiment with --quick and report the wall times.")
    p.add_argument("--out", type=Path, default=Path("runs/experiments-smoke"),
                   help="output root shared by the experiments (default: "
                        "runs/experiments-smoke)")
    p.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="execution engine (default: local)")
    p.add_argument("--jobs", type=int, default=None,
                   help="jobs at a time (default: every core)")
    p.add_argument("--only", nargs="+", default=None, metavar="NAME",
                   choices=list(EXPERIMENTS),
                   help="only these experiments (default: all, in the reference's order)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from qlap_runtime.cli import main as qlap
    from qlap_runtime.experiments.registry import EXPERIMENTS

    names = args.only or list(EXPERIMENTS)
    results = []
    for name in names:
        cmd = ["experiment", name, "--quick", "--out", str(args.out), "--engine", args.engine,
               "--no-live"]
        if args.jobs:
            cmd += ["--jobs", str(args.jobs)]
        print(f"== qlap {' '.join(cmd)}", flush=True)
        t0 = time.perf_counter()
        rc = qlap(cmd)
        results.append((name, rc, time.perf_counter() - t0))
        print(f"== {name}: exit {rc} in {results[-1][2]:.0f} s\n", flush=True)
    print(f"{'experiment':<20} {'exit':>4} {'wall time':>10}")
    for name, rc, wall in results:
        print(f"{name:<20} {rc:>4} {wall:>9.0f}s")
    print(f"{'total':<20} {'':>4} {sum(w for _, _, w in results):>9.0f}s")
    print(f"results: {args.out}/NAME-quick/RESULTS.md")
    return 0 if all(rc == 0 for _, rc, _ in results) else 1


if __name__ == "__main__":
    sys.exit(main())
