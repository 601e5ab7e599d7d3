#!/usr/bin/env python3
"""Regenerate the results page (docs/results.md and docs/results/*.png) in one command.

    .venv/bin/python scripts/learning_results.py            # core, 5 seeds x 250,000 steps
    .venv/bin/python scripts/learning_results.py --world pong --jobs 1   # pong, 5 x 100,000
                                                             # -> docs/pong/results.md

(a) runs every seed that has no RUNS/W-sS/summary.json yet, as
    ``qlap run --headless --placement sync --world W --steps N --seed S --out RUNS/W-sS --quiet``,
    --run-jobs at a time, one by default (resumable: finished seeds are skipped); (b) evaluates
each task's curve over all seeds with --jobs worker processes (``qlap curve … --every E --out
RUNS/curve-TASK``, itself resumable); (c) reads
the knowledge (``qlap report --json``, saved as RUNS/report.json); (d) draws the change DBNs
over time (Fig. 7.9); (e) writes OUT/results.md atomically. The work is done by
qlap_runtime/analysis/results.py; docs/analysis.md describes the page. Each world is judged by
its own targets (qlap_runtime/analysis/reference_values.py, ``targets_for``): core's, or pong's
(§7.10: volleys clearly above the random policy, bounded knowledge), whose steps, runs
directory and page (``docs/pong``, never docs/results.md) are the defaults with --world pong.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from qlap_runtime.argtypes import count, positive_int

if TYPE_CHECKING:
    from qlap_runtime.analysis.results import ResultsConfig


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="learning_results.py",
        description="Run the seeds that are missing, evaluate the learning curves of every "
                    "task over all seeds, read the knowledge, and write the results page "
                    "(OUT/results.md with OUT/results/*.png). Resumable: finished runs and "
                    "evaluations are reused.")
    p.add_argument("--world", default="core",
                   help="world spec of the runs (default: core); judged by its own targets "
                        "(pong: reference_values.PONG_TARGETS), core's otherwise")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5], metavar="S",
                   help="seeds, one run each (default: 1 2 3 4 5)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="agent steps of each run (default: the steps the world's targets are "
                        "set for: 250000 for core, 100000 for pong)")
    p.add_argument("--trials", type=positive_int, default=100,
                   help="evaluation trials per checkpoint and task, §7.2 (default: 100)")
    p.add_argument("--at", type=int, nargs="+", default=[], metavar="STEP",
                   help="checkpoint steps evaluated besides the multiples of --every (default: "
                        "none; e.g. 20000 230000 240000 to judge the last three checkpoints "
                        "against the end of babbling)")
    p.add_argument("--every", type=count, default=10_000, metavar="N",
                   help="evaluate the checkpoints whose step is a multiple of N, and each "
                        "run's last; 0: every checkpoint (default: 10000, the reference's "
                        "schedule)")
    p.add_argument("--jobs", type=positive_int, default=2,
                   help="worker processes of each curve's evaluation (default: 2)")
    p.add_argument("--run-jobs", type=positive_int, default=1,
                   help="runs at a time (default: 1, each run alone: two side by side on a "
                        "2-core machine each run about 1.4x slower, and the speed target is "
                        "judged on runs made alone)")
    p.add_argument("--runs-dir", type=Path, default=None,
                   help="where the runs (W-sS/), their logs, the curves (curve-TASK/) and "
                        "report.json go (default: runs/results; pong: runs/pong-results)")
    p.add_argument("--out", type=Path, default=None,
                   help="where results.md and results/*.png go (default: docs; pong: "
                        "docs/pong)")
    p.add_argument("--tasks", nargs="+", default=None, metavar="TASK",
                   help="tasks to evaluate (default: all tasks of the world)")
    return p


def make_config(args: argparse.Namespace, shown: list[str]) -> ResultsConfig:
    """The page's configuration: the options, with the defaults of the world's targets (a
    world with targets of its own, e.g. pong, gets its own steps, ``runs/W-results`` and
    ``docs/W``, so that it never overwrites core's docs/results.md)."""
    from qlap_runtime.analysis.reference_values import CORE_TARGETS, targets_for
    from qlap_runtime.analysis.results import ResultsConfig

    targets = targets_for(args.world)
    own = targets is not CORE_TARGETS
    return ResultsConfig(
        world=args.world, seeds=list(args.seeds),
        steps=args.steps if args.steps is not None else targets.steps, trials=args.trials,
        every=args.every or None, at=args.at, jobs=args.jobs, run_jobs=args.run_jobs,
        runs_dir=args.runs_dir or Path(f"runs/{targets.world}-results" if own
                                       else "runs/results"),
        out=args.out or Path(f"docs/{targets.world}" if own else "docs"),
        tasks=args.tasks, argv=shown)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from qlap_runtime.analysis import AnalysisError
    from qlap_runtime.analysis.results import build_results

    script = Path(sys.argv[0]).as_posix() if argv is None else "scripts/learning_results.py"
    shown = [script, *(sys.argv[1:] if argv is None else argv)]
    cfg = make_config(args, shown)
    try:
        return build_results(cfg, echo=lambda s: print(s, flush=True))
    except AnalysisError as exc:
        print(f"learning_results.py: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
