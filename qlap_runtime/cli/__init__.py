"""The ``qlap`` command line: :func:`main`, the ``qlap`` entry point, parses the arguments
(parser.py), checks what is wrong before anything starts (common.py) and runs the command, each
in its module — run.py with run_dir.py and run_placements.py, show.py, evaluate.py,
analysis.py (curve, report, plot), actor.py, tui.py, worlds.py; the experiment and bus commands
are qlap_runtime/experiments/cli.py's and qlap_runtime/bus/cli.py's. The public names of the
former single module are re-exported here."""

from __future__ import annotations

import sys

from ..errors import CliError, expected_error, one_line
from .actor import cmd_actor
from .analysis import cmd_analysis, cmd_plot
from .common import check_args
from .common import lag_problem as lag_problem
from .evaluate import cmd_eval
from .parser import HelpFormatter as HelpFormatter
from .parser import Parser as Parser
from .parser import build_parser as build_parser
from .parser import endpoint_arg as endpoint_arg
from .run import DEFAULT_ACTOR_LAG as DEFAULT_ACTOR_LAG
from .run import cmd_run, run_stopped, stopped_run_tail
from .run_dir import RUN_FILES as RUN_FILES
from .run_dir import default_run_dir as default_run_dir
from .run_dir import kept_checkpoint as kept_checkpoint
from .run_dir import resume_clash as resume_clash
from .run_dir import run_files_in as run_files_in
from .run_dir import source_run as source_run
from .show import cmd_show
from .tui import cmd_tui
from .worlds import cmd_worlds


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:               # named by the subcommand's parser, with its --help (not qlap's)
        parser.subcommands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        check_args(args)
        if args.command == "run":
            return cmd_run(args)
        if args.command == "actor":
            return cmd_actor(args)
        if args.command == "tui":
            return cmd_tui(args)
        if args.command == "show":
            return cmd_show(args)
        if args.command == "eval":
            return cmd_eval(args)
        if args.command in ("curve", "report"):
            return cmd_analysis(args)
        if args.command == "plot":
            return cmd_plot(args)
        if args.command == "experiment":
            from ..experiments.cli import main_experiment

            return main_experiment(args, None if argv is None else list(argv)[1:])
        if args.command == "snapshot":
            from worlds.snapshot import main_snapshot

            return main_snapshot(["--world", args.world, "--out", args.out,
                                  "--seed", str(args.seed)])
        from ..bus.cli import BUS_COMMANDS, run_bus_command

        if args.command in BUS_COMMANDS:
            return run_bus_command(args)
        if args.command == "worlds":
            return cmd_worlds(args)
    except BrokenPipeError:               # `qlap … | head`: the reader left; nothing to say
        from ..metrics import silence_stream

        silence_stream(sys.stdout)
        return 141
    except KeyboardInterrupt:
        where = getattr(args, "run_dir", None)
        print("interrupted" + (f"; what was written so far is in {where}" if where else ""),
              file=sys.stderr)
        return 130
    except Exception as exc:              # expected errors: one line, no traceback
        leaf = expected_error(exc)
        if leaf is None:
            raise
        line = f"qlap {args.command}: {one_line(leaf)}"
        if args.command == "run" and run_stopped(leaf):   # an actor placement's write failed
            line += stopped_run_tail(args, leaf)            # or its process could not restart
        print(line, file=sys.stderr)
        return leaf.code if isinstance(leaf, CliError) else 1
    return 2
