"""``qlap experiment``: the command line of the chapter-7 experiments (docs/experiments.md)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import Any

from .spec import ABLATIONS, ExperimentError

__all__ = ["DEFAULT_OUT", "add_experiment_command", "main_experiment"]

from ..argtypes import positive_int
from ..errors import CliError
from .address import ray_address

DEFAULT_OUT = Path("runs/experiments")


def add_experiment_command(sub: Any) -> None:
    """Add ``experiment`` to the ``qlap`` subcommands."""
    from .registry import EXPERIMENTS

    names = ", ".join(EXPERIMENTS)
    p = sub.add_parser(
        "experiment", help="run an experiment of chapter 7 (§7.4–7.11) with statistics and "
                           "figures",
        description="Run the experiment NAME of chapter 7 of the reference (agents × "
                    "conditions in parallel, resumable: finished runs and evaluations are "
                    "reused), then write its figures, tables, F tests and RESULTS.md into "
                    f"OUT/NAME/. Experiments: {names}. See docs/experiments.md.")
    p.add_argument("name", nargs="?", metavar="NAME", help="the experiment (see --list)")
    p.add_argument("--list", action="store_true",
                   help="list the experiments, one line each, and exit")
    p.add_argument("--agents", type=positive_int, default=None, metavar="N",
                   help="agents per condition (default: the experiment's: 20, 4 for pong; "
                        "§7.3)")
    p.add_argument("--steps", type=positive_int, default=None, metavar="N",
                   help="steps of learning (default: the experiment's: 250000; transfer "
                        "300000, landmarks-vs-random 100000)")
    p.add_argument("--trials", type=positive_int, default=None, metavar="N",
                   help="trials per evaluation of a checkpoint (default: 100, §7.2.1)")
    p.add_argument("--every", type=positive_int, default=None, metavar="N",
                   help="evaluate the checkpoints whose step is a multiple of N, and the last "
                        "(default: 10000, every checkpoint, §7.2)")
    p.add_argument("--quick", action="store_true",
                   help="the quick preset: 2 agents, 30000 steps, 20 trials (a smoke run, not "
                        "a measurement); the options above still override it")
    p.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local: a pool of spawned worker processes; ray: Ray tasks, a local "
                        "Ray with --jobs CPUs or the cluster at --address (default: local)")
    p.add_argument("--address", type=ray_address, default=None, metavar="HOST:PORT",
                   help="with --engine ray: join the Ray cluster at this address, HOST:PORT "
                        "of its head (ray start --head; port 6379 by default), "
                        "ray://HOST:PORT (Ray Client, needs ray[client]), auto (the cluster "
                        "started on this machine with ray start) or local (a local Ray); its "
                        "nodes need qlap-runtime installed and --out on shared storage; an "
                        "unreachable cluster is an error within seconds (default: start a "
                        "local Ray)")
    p.add_argument("--jobs", type=positive_int, default=None, metavar="N",
                   help="jobs at a time (default: every core of this machine; with --address, "
                        "every CPU of the cluster)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                   help="root of the agent runs (DIR/agents/, shared by the experiments) and "
                        f"of the experiment's outputs (DIR/NAME/) (default: {DEFAULT_OUT})")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="sets",
                   help="change a QLAP parameter (a field of qlap_runtime/qlap/params.py) in "
                        "every QLAP condition; repeatable (default: none)")
    p.add_argument("--ablation", action="append", default=[], metavar="NAME", dest="ablations",
                   help=f"switch on an ablation of §7.11 in every QLAP condition: "
                        f"{', '.join(ABLATIONS)}; repeatable (default: none)")
    p.add_argument("--no-live", action="store_true",
                   help="no live progress display: one line per finished job (default: live "
                        "in a terminal)")


def _spelled(exp: Any, args: argparse.Namespace, jobs: int) -> str:
    words = ["qlap", "experiment", exp.name.removesuffix("-quick"), "--agents",
             str(exp.agents), "--steps", str(exp.steps), "--trials", str(exp.trials),
             "--every", str(exp.eval_every), "--engine", args.engine, "--jobs", str(jobs),
             "--out", str(args.out)]
    if args.address:
        words += ["--address", args.address]
    if args.quick:
        words.insert(3, "--quick")
    for s in args.sets:
        words += ["--set", s]
    for a in args.ablations:
        words += ["--ablation", a]
    return shlex.join(words)


def main_experiment(args: argparse.Namespace, argv: list[str] | None = None) -> int:
    """``qlap experiment``: 0 when every job finished, 1 when some failed, 2 for bad options."""
    from .registry import EXPERIMENTS, get
    from .spec import configure, parse_set

    if args.list:
        for exp in EXPERIMENTS.values():
            print(exp.summary())
        return 0
    try:
        if args.name is None:
            raise ExperimentError("give an experiment NAME (qlap experiment --list)")
        base = get(args.name)
        sets = dict(parse_set(s) for s in args.sets)
        exp = configure(base, agents=args.agents, steps=args.steps, trials=args.trials,
                        every=args.every, quick=args.quick, sets=sets,
                        ablations=args.ablations)
        if args.address and args.engine != "ray":
            raise ExperimentError("--address goes with --engine ray")
    except ExperimentError as exc:
        print(f"qlap experiment: {exc}", file=sys.stderr)
        return 2
    from ..runtime.outputs import OutputError, check_out
    from .engine import make_backend, run_sweep
    from .report import write_report
    from .sweep import plan

    try:                                    # a cluster that does not answer: an error in
        backend = make_backend(args.engine, args.jobs, args.address)   # seconds, first
    except ExperimentError as exc:
        print(f"qlap experiment: {exc}", file=sys.stderr)
        return 2
    except CliError as exc:                 # RayUnreachable: exit status 1
        print(f"qlap experiment: {exc}", file=sys.stderr)
        return exc.code
    try:
        check_out(args.out)                 # before any run: writable, room for checkpoints
    except OutputError as exc:
        backend.close()
        print(f"qlap experiment: {exc}", file=sys.stderr)
        return 2
    sweep = plan(exp, args.out)
    typed = "qlap experiment " + shlex.join(argv if argv is not None else sys.argv[2:])
    arms = f"{len(exp.arms)} condition{'s' if len(exp.arms) != 1 else ''}"
    print(f"{exp.name} ({exp.section}): {arms} × {exp.agents} agents, "
          f"{exp.steps:,} steps, {len(exp.tasks)} task(s), {exp.trials} trials a checkpoint: "
          f"{len(sweep.runs)} agent runs, {len(sweep.evals)} evaluations under {args.out}",
          flush=True)
    try:
        result = run_sweep(sweep, backend, echo=lambda s: print(s, flush=True),
                           live=not args.no_live)
    finally:
        backend.close()
    page = write_report(sweep, typed, _spelled(exp, args, backend.slots), result)
    sps = result.steps_run / result.agent_seconds if result.agent_seconds else None
    print(f"{result.runs_done} agent runs ({result.runs_reused} reused), {result.evals_done} "
          f"evaluations ({result.evals_reused} reused) in {result.wall_s:.0f} s on "
          f"{backend.slots} {backend.name} worker(s)"
          + (f"; {sps:,.0f} agent steps/s per worker" if sps else ""))
    if result.failures:
        print(f"{len(result.failures)} failure(s):", file=sys.stderr)
        for f in result.failures[:20]:
            print(f"  {f}", file=sys.stderr)
    print(f"wrote {page} and its figures and tables")
    return 1 if result.failures else 0
