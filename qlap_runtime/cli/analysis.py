"""The commands over finished runs (qlap_runtime/analysis, docs/analysis.md):
``qlap curve`` and ``qlap report`` (:func:`cmd_analysis`) and ``qlap plot``
(:func:`cmd_plot`)."""

from __future__ import annotations

import argparse
import sys


def cmd_analysis(args: argparse.Namespace) -> int:
    """``qlap curve`` and ``qlap report`` (qlap_runtime/analysis, docs/analysis.md)."""
    from ..analysis import AnalysisError
    from ..analysis.curve import main_curve
    from ..analysis.report import main_report
    from ..runtime.outputs import OutputError, check_out, missing_dirs, remove_empty

    made = missing_dirs(args.out) if args.command == "curve" and args.out is not None else []
    try:
        if args.command == "curve" and args.out is not None:
            check_out(args.out, min_free=2**20)     # before the evaluations, not after
        if args.command == "curve":
            from ..runtime.interrupt import interrupt_on_signals

            with interrupt_on_signals():
                return main_curve(args.runs, args.task, args.trials, args.jobs, args.seed,
                                  args.out, args.world, echo=lambda s: print(s, flush=True),
                                  every=args.every, at=args.at)
        print(main_report(args.runs, as_json=args.json))
    except (AnalysisError, OutputError) as exc:
        print(f"qlap {args.command}: {exc}", file=sys.stderr)
        remove_empty(made)                          # a refused curve leaves no empty --out
        return 2
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    """``qlap plot``: each run's metrics log (and curve.csv) to RUN_DIR/metrics.png."""
    from ..analysis import AnalysisError
    from ..analysis.plot import plot_run

    status = 0
    for run_dir in args.runs:
        try:
            print(f"wrote {plot_run(run_dir)}")
        except AnalysisError as exc:
            print(f"qlap plot: {exc}", file=sys.stderr)
            status = 2
    return status
