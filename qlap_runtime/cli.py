"""The ``qlap`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="qlap",
        description="QLAP, the Qualitative Learner of Action and Perception, as a runtime.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser(
        "run", help="an agent learning autonomously in a world",
        description="Run an agent in WORLD: motor babbling (Appendix E) while the model learner "
                    "learns landmarks and DBNs (ch. 4). Shows a progress bar, writes "
                    "checkpoints every 10,000 steps and, with --out, knowledge.json and "
                    "summary.json, and prints what was learned.")
    run.add_argument("--world", default="core",
                     help="registered world spec (e.g. core, core:floating, core2d, pong, "
                          "gym:Pendulum-v1) or package.module:Factory (default: core)")
    run.add_argument("--steps", type=_positive, default=30_000,
                     help="agent steps to run (default: 30000)")
    run.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    run.add_argument("--out", type=Path, default=None,
                     help="output directory for checkpoints, knowledge.json, summary.json")
    run.add_argument("--headless", action="store_true",
                     help="no interactive UI (the only mode until the TUI exists)")
    run.add_argument("--lag", type=int, default=0,
                     help="batch lag L in steps (DESIGN.md §4; 0 = Algorithm 2)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")

    snap = sub.add_parser("snapshot", help="render a world to a PNG (MuJoCo offscreen)",
                          description="Render a world's scene to a PNG file.")
    snap.add_argument("--world", default="core")
    snap.add_argument("--out", required=True)
    snap.add_argument("--seed", type=int, default=0)

    worlds_p = sub.add_parser("worlds", help="list the registered worlds")
    worlds_p.add_argument("--json", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "run":
        return _cmd_run(args)
    if args.command == "snapshot":
        from worlds.snapshot import main_snapshot

        return main_snapshot(["--world", args.world, "--out", args.out, "--seed", str(args.seed)])
    if args.command == "worlds":
        import worlds

        names = worlds.registered()
        print(json.dumps(names) if args.json else "\n".join(names))
        return 0
    return 2


def _cmd_run(args: argparse.Namespace) -> int:
    import worlds

    from .learning_run import run_learning
    from .qlap import Params

    try:
        world = worlds.make(args.world)
    except (ValueError, ImportError) as exc:
        print(f"qlap run: {exc}", file=sys.stderr)
        return 2
    try:
        params = Params(batch_lag=args.lag)
    except ValueError as exc:
        print(f"qlap run: --lag: {exc}", file=sys.stderr)
        return 2
    progress_cb = None
    bar = None
    if not args.quiet:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeRemainingColumn,
        )

        bar = Progress(TextColumn("[bold]learning[/]"), BarColumn(), MofNCompleteColumn(),
                       TextColumn("{task.fields[rate]:>7} steps/s"),
                       TextColumn("DBNs {task.fields[dbns]:>4}  landmarks {task.fields[lms]:>3}"),
                       TimeRemainingColumn(), transient=False)
        task = bar.add_task("run", total=args.steps, rate="-", dbns=0, lms=0)
        import time

        state = {"t0": time.perf_counter()}

        def progress_cb(t: int, learner) -> None:
            if (t + 1) % 500 == 0 or t + 1 == args.steps:
                el = time.perf_counter() - state["t0"]
                lms = sum(len(s.landmarks) for s in learner.perception.spaces)
                bar.update(task, completed=t + 1, rate=f"{(t + 1) / el:,.0f}",
                           dbns=len(learner.dbns), lms=lms)

        bar.start()
    try:
        learner, summary = run_learning(world, args.steps, args.seed, args.out,
                                        params=params, progress=progress_cb)
    finally:
        if bar is not None:
            bar.stop()
        world.close()
    _print_knowledge(learner, summary)
    return 0


def _print_knowledge(learner, summary: dict) -> None:
    k = learner.knowledge()
    print(f"\n{summary['steps']} steps in {summary['wall_time_s']} s "
          f"({summary['steps_per_s']} steps/s); window k = {k['k']}")
    print("\nlandmarks:")
    for name, lms in k["landmarks"].items():
        learned = [m["label"] for m in lms if m["source"] != "initial"]
        if learned:
            print(f"  {name:8s} {', '.join(learned)}")
    reliable = [d for d in k["dbns"] if d["sufficiently_reliable"] and d["kind"] == "change"]
    print(f"\nsufficiently reliable change DBNs ({len(reliable)} of {len(k['dbns'])} DBNs):")
    for d in reliable[:40]:
        print(f"  {d['label']}  brel={d['brel']:.2f} H={d['entropy']:.2f}")
    if summary["rejected_observations"]:
        print(f"\nrejected observations: {summary['rejected_observations']}")


if __name__ == "__main__":
    sys.exit(main())
