"""The ``qlap`` command line."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, NoReturn

from .argtypes import count, goal_arg, path_arg, positive_float, positive_int
from .errors import CliError, expected_error, one_line

DEFAULT_ACTOR_LAG = 500
"""Default batch lag L of the actor placements (docs/architecture.md §2: batches pipelined, the
step chain never waits for them); the synchronous loop defaults to L = 0, Algorithm 2 to the
letter."""


class HelpFormatter(argparse.HelpFormatter):
    """argparse's help with each option's default appended as ``(default: …)`` unless its help
    already states one (or the default is None/False, which says nothing)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("default" in text or action.required or default is None or default is False
                or default == [] or default is argparse.SUPPRESS or not action.option_strings):
            return text
        return f"{text} (default: %(default)s)"


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    from . import __version__

    try:
        return version("qlap-runtime")
    except PackageNotFoundError:        # a source tree that was not installed
        return __version__


def endpoint_arg(text: str) -> str:
    """A Zenoh endpoint ``PROTOCOL/HOST:PORT``, checked before the run starts."""
    from .bus.config import BusConfigError, validate_endpoint

    try:
        return validate_endpoint(text, "endpoint")
    except BusConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("endpoint: ")) from None


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error, naming the command and where its help is (instead of
    the usage block first); exit code 2 as argparse's. Subcommands' parsers are of this class
    too (``add_subparsers`` uses the parent's)."""

    subcommands: dict[str, argparse.ArgumentParser]
    """The subcommands' parsers by name (set by :func:`build_parser`)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="qlap", formatter_class=HelpFormatter,
        description="QLAP, the Qualitative Learner of Action and Perception, as a runtime.")
    p.add_argument("--version", action="version", version=f"qlap {_version()}",
                   help="print the version and exit")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser(
        "run", help="an agent learning autonomously in a world",
        description="Run a QLAP agent in WORLD (Algorithm 2): motor babbling for the first "
                    "20,000 steps, then practice of learned actions chosen by IAC. Shows a "
                    "progress bar (steps/s, DBNs, plans, landmarks; plain lines when stdout is "
                    "not a terminal), writes into the run directory OUT a checkpoint every "
                    "10,000 steps (OUT/checkpoints/), a metrics line every 1,000 steps "
                    "(OUT/metrics.jsonl) and, at the end, OUT/knowledge.json, OUT/summary.json "
                    "and OUT/checkpoints/final (docs/outputs.md), and prints what was learned.")
    run.add_argument("--world", default=None,
                     help="registered world spec (e.g. core, core:floating, core2d, pong, "
                          "gym:Pendulum-v1) or package.module:Factory (default: core; with "
                          "--resume, the world the checkpoint records)")
    run.add_argument("--steps", type=positive_int, default=250_000,
                     help="agent steps to run (default: 250000, the reference's exploration, "
                          "§7.2: a few minutes here; in the terminal UI q quits at any time "
                          "and keeps what was learned)")
    run.add_argument("--seed", type=count, default=None,
                     help="random seed (default: 0; with --resume, the checkpoint's, which a "
                          "different --seed cannot change)")
    run.add_argument("--out", type=path_arg, default=None,
                     help="run directory for checkpoints, metrics.jsonl, knowledge.json, "
                          "summary.json (default: runs/WORLD-YYYYmmdd-HHMMSS-sSEED/)")
    run.add_argument("--keep-checkpoints", type=count, default=None, metavar="N",
                     help="keep only the newest N of the every-10,000-steps checkpoints "
                          "(0: none, only checkpoints/final; default: keep all, as the "
                          "evaluation protocol of §7.2 evaluates each)")
    run.add_argument("--headless", action="store_true",
                     help="no terminal UI: a progress bar and a final summary (the default "
                          "when stdout is not a terminal)")
    run.add_argument("--placement", choices=("embedded", "processes", "sync"), default=None,
                     help="embedded (default): the actors of docs/runtime.md as trio tasks on "
                          "one socket-less Zenoh session; processes: process groups around a "
                          "router (see --groups), a dead group restarted from its snapshots; "
                          "sync: the synchronous reference loop (Algorithm 2) "
                          "without a bus, fastest. Same seed and lag give identical knowledge. "
                          "In a terminal without --headless, `qlap run` opens the terminal UI "
                          "on its own agent process unless a placement is given")
    run.add_argument("--groups", default=None, metavar="LAYOUT",
                     help="(processes) which actors share a process: two (default): the step "
                          "chain (world, perception, executor) with the planner, and both "
                          "learners on one learner, a process each; each: one process per "
                          "actor (any actor but the world restarts alone); or groups spelled "
                          "out, actors joined by '+', groups by ',' (e.g. "
                          "world+perception+executor+planner,contingency+landmarks)")
    run.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                     help="lockstep: the world waits for the executor and due deltas "
                          "(deterministic); realtime: the world ticks at --hz, deltas apply "
                          "on arrival, late and missed ticks are counted (embedded and "
                          "processes placements)")
    run.add_argument("--hz", type=positive_float, default=None,
                     help="tick rate of the realtime clock (default 100; with --clock "
                          "realtime only)")
    run.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                     type=endpoint_arg,
                     help="also listen on ENDPOINT (e.g. tcp/127.0.0.1:7447) so outside "
                          "subscribers (qlap tui/record/echo --connect) can attach "
                          "(embedded placement and the terminal UI); they authenticate with "
                          "<out>/bus-credentials.json, written for the run")
    run.add_argument("--record", type=path_arg, default=None, metavar="FILE.mcap",
                     help="record every bus message of the run to an MCAP file "
                          "(embedded and processes placements)")
    run.add_argument("--lag", type=int, default=None,
                     help="batch lag L in steps (docs/architecture.md §2): a batch computed "
                          "from the data up to t is applied at t + L while the step chain runs "
                          "on; 0 = Algorithm 2 to the letter (default: 500 for embedded and "
                          "processes, 0 for sync)")
    run.add_argument("--babble-steps", type=int, default=None,
                     help="length of the initial motor-babbling period (default: 20000, §6.1)")
    run.add_argument("--resume", type=path_arg, default=None,
                     help="continue from an agent checkpoint directory into a new run "
                          "directory: a lockstep checkpoint of any placement, in any "
                          "placement, exactly; a realtime one only in sync, inexactly; "
                          "otherwise refused in one line")
    run.add_argument("--quiet", action="store_true",
                     help="no progress bar (no progress lines)")

    show = sub.add_parser("show", help="print learned knowledge in the reference's notation",
                          description="Print the knowledge of a run directory (its "
                                      "knowledge.json) or of a checkpoint directory, grouped "
                                      "by action like Tables 8.2–8.6.")
    show.add_argument("path", type=path_arg, help="run directory or checkpoint directory")
    show.add_argument("--all", action="store_true",
                      help="also list DBNs that are not plans")

    ev = sub.add_parser("eval", help="evaluate a checkpoint on a task (§7.2)",
                        description="Run the §7.2 protocol: TRIALS trials of TASK, each up to "
                                    "300 steps, −0.01 a step and +9.99 on success, the agent "
                                    "in goal mode with learning off. Prints the mean reward "
                                    "with its standard error and the success rate.")
    ev.add_argument("--checkpoint", type=path_arg, default=None,
                    help="agent checkpoint directory (not needed with --policy random)")
    ev.add_argument("--world", default=None,
                    help="world spec (default: the world the checkpoint records, else core)")
    ev.add_argument("--task", required=True, help="task name, e.g. move_block, hit_floor, pickup")
    ev.add_argument("--trials", type=positive_int, default=100, help="trials of the task")
    ev.add_argument("--seed", type=count, default=0,
                    help="seed of the trials' set-ups (the same set-ups for every checkpoint)")
    ev.add_argument("--policy", choices=("qlap", "random"), default="qlap",
                    help="qlap (the checkpoint's agent) or random (the random-motor baseline)")
    ev.add_argument("--goal", type=goal_arg, default=None, metavar="VAR=VALUE",
                    help="the agent pursues this goal in every trial instead of the task's "
                         "(e.g. T_L.dot=+ in hit_floor: how often pushing the block left "
                         "knocks it off); the task still judges each trial")
    ev.add_argument("--trace", type=path_arg, default=None, metavar="FILE.jsonl",
                    help="write every step of the trials as JSON lines: the goal, the agent's "
                         "mode and call list, whether a plan waits with the motors held, "
                         "the motor command; then each trial's reward (docs/analysis.md)")
    ev.add_argument("--json", action="store_true", help="print the result as JSON")

    curve = sub.add_parser(
        "curve", help="evaluate every checkpoint of runs on a task: curve.csv and curve.png",
        description="Evaluate every checkpoint of each RUN_DIR (checkpoints/step-NNNNNNN/, "
                    "and final unless a step-N has its step; with --every N only the steps "
                    "that are multiples of N, and the last) on TASK with the protocol of "
                    "`qlap eval` (§7.2), in parallel worker processes, and the random policy "
                    "on the same world, task, trials and seed. Writes curve.csv (resumable: "
                    "evaluations already there are not recomputed) and curve.png (mean reward "
                    "against steps with standard-error bars, the random policy dashed; several "
                    "runs: their mean and the standard error across them, as Figs. 7.2–7.4). "
                    "See docs/analysis.md.")
    curve.add_argument("runs", nargs="+", type=path_arg, metavar="RUN_DIR",
                       help="run directories written by `qlap run --out` (several: seeds, "
                            "drawn as their mean)")
    curve.add_argument("--task", required=True,
                       help="task name, e.g. move_block, hit_floor, pickup")
    curve.add_argument("--trials", type=positive_int, default=100,
                       help="trials per checkpoint (default: 100)")
    curve.add_argument("--jobs", type=positive_int, default=None,
                       help="worker processes (default: os.cpu_count())")
    curve.add_argument("--seed", type=count, default=0,
                       help="seed of the trials, the same set-ups for every checkpoint "
                            "(default: 0)")
    curve.add_argument("--out", type=path_arg, default=None,
                       help="where curve.csv and curve.png go (default: RUN_DIR; required "
                            "with several runs)")
    curve.add_argument("--world", default=None,
                       help="world spec, when the checkpoints do not record theirs (default: "
                            "the world of RUN_DIR/summary.json)")
    curve.add_argument("--every", type=positive_int, default=None, metavar="N",
                       help="evaluate only the checkpoints whose step is a multiple of N, "
                            "plus each run's last (default: every checkpoint)")
    curve.add_argument("--at", type=positive_int, nargs="+", default=(), metavar="STEP",
                       help="with --every: these steps' checkpoints too (e.g. --at 20000 "
                            "230000 240000: the end of babbling and the last three)")

    report = sub.add_parser(
        "report", help="what runs know, beside the reference's figures (ch. 8)",
        description="Print the knowledge figures of each run (its knowledge.json, "
                    "or its latest checkpoint) beside the reference's: window k, change and "
                    "magnitude DBNs, landmarks per variable, values narrower than the "
                    "resolution, the u_x friction landmarks, rel(a) of a(ḣ_x,[+]), "
                    "a(Ṫ_L,[+]) and a(T,true) with their plans; then the knowledge over time "
                    "(change and magnitude DBNs, plans, landmarks at every checkpoint) with the "
                    "verdict 'change DBNs ≤ 600 and not growing after 150k', and each run's "
                    "speed (summary.json steps_per_s). Several runs: one column each and the "
                    "mean. See docs/analysis.md.")
    report.add_argument("runs", nargs="+", type=path_arg, metavar="RUN_DIR",
                        help="run directories (or agent checkpoint directories)")
    report.add_argument("--json", action="store_true",
                        help="print the figures as JSON (reference, runs, mean)")

    plot = sub.add_parser(
        "plot", help="draw a run's metrics log (and learning curve) to RUN_DIR/metrics.png",
        description="Draw each RUN_DIR's metrics log (metrics.jsonl, a line every 1,000 steps: "
                    "change and magnitude DBNs, plans, landmarks, sufficiently reliable "
                    "actions, IAC choices and babbling, steps/s) and, if the run has a "
                    "curve.csv (qlap curve), its learning curve, into RUN_DIR/metrics.png "
                    "(docs/outputs.md).")
    plot.add_argument("runs", nargs="+", type=path_arg, metavar="RUN_DIR",
                      help="run directories written by `qlap run`")

    snap = sub.add_parser("snapshot", help="render a world to a PNG (MuJoCo offscreen)",
                          description="Render a world's scene to a PNG file.")
    snap.add_argument("--world", default="core",
                      help="world spec, e.g. core:secondary:aligned")
    snap.add_argument("--out", required=True, metavar="FILE.png",
                      help="PNG file to write (its directory must exist)")
    snap.add_argument("--seed", type=count, default=0, help="seed of the world's placement")

    from .experiments.cli import add_experiment_command

    add_experiment_command(sub)

    from .bus.cli import add_bus_commands

    add_bus_commands(sub)

    actor = sub.add_parser(
        "actor", help="run one actor of a distributed run (connects to a router)",
        description="Run one actor (world, perception, contingency, landmarks, planner, executor) "
                    "on this machine, connected to a Zenoh router (qlap router). Start every "
                    "actor of the run with the same --run, --world, --steps, --seed and "
                    "learning options; the world starts stepping when the others are alive.")
    actor.add_argument("name", choices=("world", "perception", "contingency", "landmarks",
                                        "planner", "executor"), help="the actor to run here")
    from .bus.cli import connection_args

    connection_args(actor)
    actor.add_argument("--run", required=True, help="run id shared by every actor of the run")
    actor.add_argument("--world", default="core",
                       help="world spec (see qlap worlds), the same for every actor")
    actor.add_argument("--steps", type=positive_int, default=30_000, help="agent steps to run")
    actor.add_argument("--seed", type=count, default=0, help="random seed")
    actor.add_argument("--lag", type=count, default=500, help="batch lag L in steps")
    actor.add_argument("--babble-steps", type=count, default=None,
                       help="length of the initial motor-babbling period (default: 20000, "
                            "§6.1)")
    actor.add_argument("--out", type=path_arg, default=None,
                       help="(executor) where to write knowledge.json, checkpoints")

    tui_p = sub.add_parser("tui", help="attach the terminal UI to a running agent",
                           description="Open the Textual UI on a run reachable through a Zenoh "
                                       "endpoint (qlap run --listen, or a router).")
    tui_p.add_argument("--connect", action="append", required=True, metavar="ENDPOINT",
                       help="endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    tui_p.add_argument("--run", default=None, help="run id (default: the first one heard)")
    tui_p.add_argument("--credentials", type=path_arg, default=None, metavar="FILE",
                       help="the run's bus-credentials.json (user tui; default: "
                            "$QLAP_CREDENTIALS)")

    worlds_p = sub.add_parser(
        "worlds", help="list the registered worlds with their descriptions and tasks",
        description="One line per registered world spec (each variant too): the spec, what "
                    "it is and its tasks (for qlap eval --task). Any module:Factory (a "
                    "top-level or dotted module) is a world too.")
    worlds_p.add_argument("--json", action="store_true",
                          help="print a JSON list of {spec, description, tasks}")
    for parser in sub.choices.values():
        parser.formatter_class = HelpFormatter
    p.subcommands = dict(sub.choices)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:               # named by the subcommand's parser, with its --help (not qlap's)
        parser.subcommands[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        _check_args(args)
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "actor":
            return _cmd_actor(args)
        if args.command == "tui":
            return _cmd_tui(args)
        if args.command == "show":
            return _cmd_show(args)
        if args.command == "eval":
            return _cmd_eval(args)
        if args.command in ("curve", "report"):
            return _cmd_analysis(args)
        if args.command == "plot":
            return _cmd_plot(args)
        if args.command == "experiment":
            from .experiments.cli import main_experiment

            return main_experiment(args, None if argv is None else list(argv)[1:])
        if args.command == "snapshot":
            from worlds.snapshot import main_snapshot

            return main_snapshot(["--world", args.world, "--out", args.out,
                                  "--seed", str(args.seed)])
        from .bus.cli import BUS_COMMANDS, run_bus_command

        if args.command in BUS_COMMANDS:
            return run_bus_command(args)
        if args.command == "worlds":
            return _cmd_worlds(args)
    except BrokenPipeError:               # `qlap … | head`: the reader left; nothing to say
        from .metrics import silence_stream

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
        if args.command == "run" and _run_stopped(leaf):   # an actor placement's write failed
            line += _stopped_run_tail(args, leaf)            # or its process could not restart
        print(line, file=sys.stderr)
        return leaf.code if isinstance(leaf, CliError) else 1
    return 2


def _check_args(args: argparse.Namespace) -> None:
    """Inputs wrong before anything starts: a negative --babble-steps, an output file whose
    directory does not exist (--record, snapshot/record --out)."""
    babble = getattr(args, "babble_steps", None)
    if babble is not None and babble < 0:
        raise CliError(f"--babble-steps {babble}: expected a non-negative integer")
    outputs = {"run": ("record", "--record"), "snapshot": ("out", "--out"),
               "record": ("out", "--out")}
    attr, flag = outputs.get(args.command, (None, None))
    value = getattr(args, attr, None) if attr else None
    if value is not None:
        problem = _file_problem(Path(value))
        if problem is None and args.command != "snapshot" and Path(value).exists():
            problem = "exists: give a new file (a recording is never overwritten)"
        if problem is not None:
            raise CliError(f"{flag} {value}: {problem}")


def _file_problem(path: Path) -> str | None:
    """Why an output file cannot be written at ``path``, found before any work starts (a
    directory there, no parent directory, or a parent that refuses a probe file); None if it
    can."""
    import tempfile

    if path.is_dir():
        return "is a directory, not a file"
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        return f"directory {parent} does not exist"
    try:                                # a probe, as the file is written: a temp file there
        fd, probe = tempfile.mkstemp(dir=parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        return f"cannot write in {parent} ({exc.strerror or exc})"
    return None


def _cmd_tui(args: argparse.Namespace) -> int:
    """``qlap tui --connect``: the UI on a remote run, once the endpoint answers."""
    import zenoh

    from tui import QlapApp

    from .bus.auth import UI_USER
    from .bus.cli import connect_failure, credentials_for
    from .bus.config import client_config

    user, password = credentials_for(args.credentials, UI_USER)
    auth = {"user": user, "password": password} if user else {}
    try:
        zenoh.open(client_config(args.connect, **auth)).close()
    except zenoh.ZError as exc:
        raise CliError(connect_failure(args.connect, one_line(exc), args.credentials),
                       code=1) from None
    try:
        app = QlapApp(connect=args.connect, run_id=args.run, **auth)
    except ValueError as exc:
        raise CliError(f"--run {args.run}: {exc}") from None
    app.run()
    return 0 if app.return_code in (0, None) else 1


def _cmd_worlds(args: argparse.Namespace) -> int:
    """``qlap worlds``: each registered spec (variants too) with its description and tasks."""
    import worlds
    from worlds.registry import describe

    rows = []
    for spec in worlds.registered():
        try:
            world = worlds.make(spec)
        except Exception as exc:       # e.g. an optional engine missing: still list the spec
            if expected_error(exc) is None and not isinstance(exc, ImportError | ValueError):
                raise
            tasks, note = [], f"(cannot be made here: {one_line(exc)})"
        else:
            tasks, note = sorted(world.tasks), ""
            world.close()
        description = describe(spec) or describe(spec.split(":", 1)[0])
        rows.append({"spec": spec, "description": " ".join(filter(None, (description, note))),
                     "tasks": tasks})
    if args.json:
        print(json.dumps(rows))
        return 0
    width = max(len(r["spec"]) for r in rows)
    for r in rows:
        tasks = ", ".join(r["tasks"]) or "none (no evaluation task)"
        print(f"{r['spec']:{width}}  {r['description']}; tasks: {tasks}")
    print("any module:Factory is a world too, e.g. mypackage.worlds:make_world")
    return 0


def _make_world(spec: str, command: str):
    import worlds

    try:
        return worlds.make(spec)
    except Exception as exc:
        if expected_error(exc) is None and not isinstance(
                exc, ValueError | ImportError | AttributeError):
            raise
        print(f"qlap {command}: --world {spec}: {one_line(exc)}", file=sys.stderr)
        return None


def default_run_dir(world: str, seed: int, root: Path = Path("runs")) -> Path:
    """``runs/<world>-<YYYYmmdd-HHMMSS>-s<seed>``, the world spec made a file name; ``-2``,
    ``-3``, … when a run of the same second has it already."""
    import re
    import time

    name = re.sub(r"[^A-Za-z0-9._-]+", "_", world).strip("._") or "world"
    base = f"{name}-{time.strftime('%Y%m%d-%H%M%S')}-s{seed}"
    path, n = root / base, 1
    while path.exists():
        n += 1
        path = root / f"{base}-{n}"
    return path


def source_run(checkpoint: Path) -> Path | None:
    """The run directory a checkpoint belongs to (``<run>/checkpoints/<name>``, links
    followed), or None for a checkpoint outside a run."""
    for path in (Path(checkpoint).absolute(), Path(checkpoint).resolve()):
        if path.parent.name == "checkpoints":
            return path.parent.parent.resolve()
    return None


def resume_clash(checkpoint: Path, out: Path | None) -> str | None:
    """Why ``--resume checkpoint --out out`` would write over the run the checkpoint comes
    from (its knowledge.json, summary.json, final/ and later checkpoints), or None. Without
    ``--out`` the run goes to a new default directory."""
    run = source_run(checkpoint)
    if run is None or out is None:
        return None
    target = Path(out).resolve()
    if target == run or target.is_relative_to(run) or run.is_relative_to(target):
        return (f"--out {out} would write over the run the checkpoint comes from ({run}): "
                "give a new --out")
    return None


RUN_FILES = ("knowledge.json", "summary.json", "metrics.jsonl", "checkpoints", "actors")
"""What a run writes into its directory (docs/outputs.md): a directory holding any of them
holds a run."""


def run_files_in(out: Path) -> list[str]:
    """The names of :data:`RUN_FILES` present in ``out`` (none if it does not exist)."""
    out = Path(out)
    return [name for name in RUN_FILES if (out / name).exists()] if out.is_dir() else []


def _prepare_out(args: argparse.Namespace) -> Path | None:
    """The run directory (``--out`` or the default), created and checked writable with a
    probe file and for room for a checkpoint before the run starts
    (:func:`~qlap_runtime.runtime.outputs.check_out`), and refused if it already holds a run
    (its checkpoints and metrics would mix with this one's); None after a one-line error."""
    from .runtime.outputs import OutputError, check_out

    out = args.out if args.out is not None else default_run_dir(args.world, args.seed)
    held = run_files_in(out)
    if held:
        print(f"qlap run: --out {out} already holds a run ({', '.join(held)}); a second run "
              "there would mix the two: give a new directory", file=sys.stderr)
        return None
    try:
        check_out(out)
    except OutputError as exc:
        print(f"qlap run: {exc}", file=sys.stderr)
        return None
    args.run_dir = out
    print(f"run directory: {out}", flush=True)
    return out


def lag_problem(lag: int) -> str | None:
    """Why ``--lag`` cannot be ``lag`` (one line), or None: a batch's delta is applied before
    the next batch starts, so 0 <= L < the DBN batch period (Algorithm 2)."""
    from .qlap import Params

    period = Params().dbn_period
    if 0 <= lag < period:
        return None
    return (f"--lag {lag}: must be in [0, {period}) — a batch's delta is applied before the "
            f"next batch, every {period} steps, starts")


def _cmd_run(args: argparse.Namespace) -> int:
    try:
        return _cmd_run_inner(args)
    except OSError as exc:               # e.g. the disk filled up during the run
        print(f"qlap run: {exc}" + _stopped_run_tail(args, exc), file=sys.stderr)
        return 1


def _stopped_run_tail(args: argparse.Namespace, exc: BaseException) -> str:
    """What follows the error of a stopped run: its directory (for a failed write) and the
    checkpoint it keeps."""
    where = getattr(args, "run_dir", None)
    return ((f" (run directory {where})" if where and isinstance(exc, OSError) else "")
            + kept_checkpoint(where))


def _run_stopped(exc: BaseException) -> bool:
    """A run an actor placement stopped: a write failed (OSError) or an actor could not be
    restarted (``ActorFailed``)."""
    from .errors import ActorFailed

    return isinstance(exc, OSError | ActorFailed)


def kept_checkpoint(run_dir: Path | None) -> str:
    """What a failed run keeps: its newest complete periodic checkpoint (one with agent.json;
    checkpoints are written whole or not at all) and how to go on from it, or ""."""
    if run_dir is None:
        return ""
    from .qlap.checkpoint import AGENT_FILE, WORLD_FILE

    done = sorted(d for d in (Path(run_dir) / "checkpoints").glob("step-*")
                  if (d / AGENT_FILE).is_file())
    if not done:
        return "; no checkpoint was kept"
    # A realtime run's checkpoint has no world state: only the sync loop continues it (inexactly).
    sync = "" if (done[-1] / WORLD_FILE).is_file() else " --placement sync"
    return (f"; kept: {done[-1]} (go on from it: qlap run --resume {done[-1]}{sync} "
            "--out NEW_DIR)")


def _cmd_run_inner(args: argparse.Namespace) -> int:
    from .qlap import Params
    from .qlap.checkpoint import checkpoint_seed

    if args.world is None:            # a resumed agent goes on in the world it learned in
        from .analysis.runs import recorded_world

        recorded = recorded_world(args.resume) if args.resume is not None else None
        args.world = recorded or "core"
    if args.resume is not None:
        seed = checkpoint_seed(args.resume)
        given = [flag for flag, value in (("--lag", args.lag),
                                          ("--babble-steps", args.babble_steps))
                 if value is not None]
        if args.seed is not None and seed is not None and args.seed != seed:
            given.insert(0, f"--seed {args.seed} (the checkpoint's is {seed})")
        if given:
            print(f"qlap run: {', '.join(given)} cannot change a resumed agent: it goes on with "
                  "its checkpoint's random state, lag and babbling (drop --resume for a new "
                  "run)", file=sys.stderr)
            return 2
        args.seed = seed if seed is not None else args.seed
    if args.seed is None:
        args.seed = 0
    interactive = sys.stdout.isatty() and not args.headless
    tui = interactive and args.placement is None and args.resume is None
    if interactive and args.placement is None and args.resume is not None:
        print("qlap run: --resume goes on headless (the terminal UI starts new runs only)",
              file=sys.stderr)
    args.placement = args.placement or "embedded"
    if args.lag is None:
        args.lag = 0 if args.placement == "sync" or tui else DEFAULT_ACTOR_LAG
    problem = _run_args_problem(args, tui, interactive)
    params = None
    if problem is None:
        try:
            changes = {"batch_lag": args.lag}
            if args.babble_steps is not None:
                changes["babble_steps"] = args.babble_steps
            params = Params(**changes)
        except ValueError as exc:
            problem = str(exc)
    if problem is not None:                 # every flag is checked before a world is made
        print(f"qlap run: {problem}", file=sys.stderr)
        return 2
    assert params is not None
    args.hz = 100.0 if args.hz is None else args.hz
    world = _make_world(args.world, "run")
    if world is None:
        return 2
    if args.resume is not None and (
            mismatch := _world_mismatch(args.resume, world, args.world)) is not None:
        print(f"qlap run: --resume: {mismatch}", file=sys.stderr)
        world.close()
        return 2
    if tui:
        world.close()                       # made to check the spec; the UI's agent makes its own
        return _run_tui(args)
    if args.placement != "sync":
        return _run_actors(args, world, params)
    try:
        return _run_sync(args, world, params)
    finally:
        world.close()


def _port_problem(endpoint: str) -> str | None:
    """Why a ``tcp/HOST:PORT`` endpoint cannot be listened on (its port taken), or None; found
    before the run starts, not from the bus in the middle of it."""
    import re
    import socket

    m = re.fullmatch(r"tcp/(\[?[^\]]*\]?|[^:]+):(\d+)", endpoint)
    if m is None or m.group(2) == "0":
        return None
    host = m.group(1).strip("[]")
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.bind((host, int(m.group(2))))
    except OSError as exc:
        return f"--listen {endpoint}: cannot listen there ({exc.strerror or exc})"
    return None


def _run_args_problem(args: argparse.Namespace, tui: bool, interactive: bool) -> str | None:
    """Why ``qlap run``'s flags do not go together (one line), or None."""
    for endpoint in args.listen or ():
        if (problem := _port_problem(endpoint)) is not None:
            return problem
    if args.groups is not None and args.placement != "processes":
        return f"--groups {args.groups} goes with --placement processes"
    if (problem := lag_problem(args.lag)) is not None:
        return problem
    if args.hz is not None and args.clock != "realtime":
        return f"--hz {args.hz:g} goes with --clock realtime"
    if tui:
        ignored = [flag for flag, given in (("--record", args.record is not None),
                                            ("--clock realtime", args.clock == "realtime"))
                   if given]
        if ignored:
            return (f"{' and '.join(ignored)} go with --headless (the terminal UI runs its "
                    "agent in lockstep, without recording; `qlap record --connect` records a "
                    "run started with --listen)")
        return None
    if args.clock == "realtime" and args.placement == "sync":
        return "--clock realtime needs --placement embedded or processes"
    if args.placement == "sync" and (args.record is not None
                                     or (args.listen and not interactive)):
        return ("--record and --listen need the bus: use --placement embedded (or the "
                "terminal UI for --listen)")
    return None


def _run_sync(args: argparse.Namespace, world: Any, params: Any) -> int:
    """``qlap run --placement sync``: Algorithm 2 in this process, with a progress bar."""
    from .agent_run import run_agent
    from .metrics import PlainProgress
    from .placements.resume import in_flight_problem
    from .qlap.checkpoint import CheckpointError, load_agent

    agent = None
    restored = False
    if args.resume is not None:
        clash = resume_clash(args.resume, args.out)
        if clash is not None:
            print(f"qlap run: --resume: {clash}", file=sys.stderr)
            return 2
        try:
            agent = load_agent(args.resume)
            problem = in_flight_problem(args.resume, agent.learner.params,
                                        agent.step_count + 1, "sync")
            if problem is not None:
                raise CheckpointError(problem)
            restored = _restore_world(world, args.resume)
        except CheckpointError as exc:
            print(f"qlap run: --resume: {exc}", file=sys.stderr)
            return 2
    out = _prepare_out(args)
    if out is None:
        return 2
    progress_cb = None
    bar = None
    plain = None
    if not args.quiet and not sys.stdout.isatty():
        plain = PlainProgress(args.steps, start=agent.step_count + 1 if agent else 0)
    elif not args.quiet:
        import time

        from .runtime.progress import progress_bar

        bar = progress_bar(args.steps)
        task = bar.task_ids[0]
        state = {"t0": time.perf_counter(), "first": None}

        def progress_cb(t: int, agent) -> None:
            if state["first"] is None:
                state["first"] = t
            done = t - state["first"] + 1
            if done % 500 == 0 or done == args.steps:
                from .metrics import knowledge_counts

                el = time.perf_counter() - state["t0"]
                n = knowledge_counts(agent)          # as in summary.json
                bar.update(task, completed=done, rate=f"{done / el:,.0f}",
                           dbns=n["dbns"], plans=n["plans"], lms=n["landmarks"])

        bar.start()
    from .runtime.interrupt import stop_on_signals

    try:
        with stop_on_signals() as stop:
            agent, summary = run_agent(world, args.steps, args.seed, out, params=params,
                                       progress=progress_cb, agent=agent,
                                       keep_checkpoints=args.keep_checkpoints,
                                       on_metrics=plain, restored=restored, stop=stop)
    finally:
        if bar is not None:
            bar.stop()
    if plain is not None:
        plain.final(summary)
    print(f"\n{summary['steps']} steps in {summary['wall_time_s']} s "
          f"({summary['steps_per_s']} steps/s); k = {summary['k']}, {summary['dbns']} DBNs, "
          f"{summary['plans']} plans, {summary['landmarks']} landmarks, "
          f"{summary['reliable_actions']} sufficiently reliable actions")
    if summary["rejected_observations"]:
        print(f"rejected observations: {summary['rejected_observations']} "
              f"(first: {summary['rejected_examples'][0]})")
    from .analysis.show import format_knowledge

    print(format_knowledge(agent.knowledge(), limit=25))
    _print_written(out)
    if "interrupted_at" in summary:
        print(f"qlap run: interrupted before step {summary['interrupted_at']}; what was "
              f"learned is written — go on from it: qlap run --resume {out}/checkpoints/final "
              "--placement sync --out NEW_DIR", file=sys.stderr)
        return 130
    return 0


def _restore_world(world, checkpoint: Path) -> bool:
    """Put ``world`` in the state a checkpoint saved (``world.json``): True when it holds one;
    a checkpoint without one (written before world states were saved, or by a world that
    cannot save its state) leaves the world to ``reset(seed)``, which ``qlap`` says."""
    from .qlap.checkpoint import (
        load_world_state,
        resolve_checkpoint,
        restore_world,
        statistics_missing,
    )

    state = load_world_state(checkpoint)
    if state is None:
        print("qlap run: --resume: the checkpoint holds no world state; the world starts "
              "again from reset(seed), so the run will differ from an uninterrupted one",
              file=sys.stderr)
        return False
    restore_world(world, state, resolve_checkpoint(checkpoint) / "world.json")
    if statistics_missing(checkpoint):
        print("qlap run: --resume: the checkpoint's learner has no pair statistics (an actor "
              "placement's checkpoint without its stats part); the run will differ from an "
              "uninterrupted one", file=sys.stderr)
    return True


def _print_written(out: Path) -> None:
    from .analysis.plot import plot_run_if_possible

    picture = plot_run_if_possible(out)
    drawn = f", {picture.name}" if picture is not None else ""
    print(f"\nwrote {out}/: knowledge.json, summary.json, metrics.jsonl{drawn}, checkpoints/ "
          f"(qlap plot {out} draws them again, with a learning curve after qlap curve)")


def _run_tui(args: argparse.Namespace) -> int:
    """``qlap run`` in a terminal: the agent in its own process, the UI here (docs/tui.md)."""
    from tui import DriverProcess, run_process

    out = _prepare_out(args)
    if out is None:
        return 2
    overrides: dict = {}
    if args.babble_steps is not None:
        overrides["babble_steps"] = args.babble_steps
    if args.lag:
        overrides["batch_lag"] = args.lag
    proc = DriverProcess(args.world, params=overrides, seed=args.seed, steps=args.steps,
                         out=out, listen=args.listen, checkpoint_dir=out / "checkpoints",
                         keep_checkpoints=args.keep_checkpoints)
    run_process(proc)
    _print_written(out)
    return 0 if proc.exitcode in (0, None) else 1


def _run_actors(args: argparse.Namespace, world, params) -> int:
    """``qlap run --placement embedded|processes``: the actor runtime in lockstep."""
    import threading

    from .agent_run import params_for_world
    from .bus import keys
    from .metrics import METRICS_FILE, PlainProgress, follow_metrics
    from .placements.launcher import run_embedded, run_processes
    from .runtime.context import RunContext

    params = params_for_world(world, params)
    world.close()
    if args.placement == "processes" and args.listen:
        print("qlap run: --listen goes with --placement embedded; with processes, outside "
              "subscribers connect to the router's endpoint, printed at the start",
              file=sys.stderr)
        return 2
    groups = None
    if args.groups is not None:
        from .placements.groups import GroupsError, parse_groups

        try:
            groups = parse_groups(args.groups)
        except GroupsError as exc:
            print(f"qlap run: --groups: {exc}", file=sys.stderr)
            return 2
    ctx = RunContext(keys.new_run_id(), args.world, args.steps, args.seed, params,
                     clock=args.clock, hz=args.hz, keep_checkpoints=args.keep_checkpoints,
                     placement=args.placement)
    if args.resume is not None:
        # Exact or refused (one line, with what to use instead), before anything is written.
        from .placements.resume import ResumeRefused, resume_context
        from .qlap.checkpoint import CheckpointError

        clash = resume_clash(args.resume, args.out)
        if clash is not None:
            print(f"qlap run: --resume: {clash}", file=sys.stderr)
            return 2
        try:
            ctx = resume_context(ctx, args.resume)
        except (ResumeRefused, CheckpointError) as exc:
            print(f"qlap run: --resume: {exc}", file=sys.stderr)
            return 2
    params = ctx.params
    out = _prepare_out(args)
    if out is None:
        return 2
    ctx = ctx.with_(out=out)
    resumed = f", from step {ctx.start} of {ctx.resume_checkpoint}" \
        if ctx.resume_checkpoint is not None else ""
    from .placements.groups import DEFAULT_GROUPS

    layout = f" (groups {args.groups or DEFAULT_GROUPS})" if args.placement == "processes" \
        else ""
    print(f"run {ctx.run_id}: {args.steps} steps of {args.world}, placement "
          f"{args.placement}{layout}, {args.clock}, lag {params.batch_lag}{resumed}",
          file=sys.stderr)
    from .bus.auth import CREDENTIALS_FILE

    credentials = out / CREDENTIALS_FILE
    if args.listen:
        print(f"listening on {', '.join(args.listen)} with authentication: qlap tui --connect "
              f"{args.listen[0]} --credentials {credentials}", file=sys.stderr)
    # Progress: the rich bar fed from the bus in a terminal (embedded); otherwise plain lines
    # from the metrics log the executor writes (the same counts as the summary).
    plain = None
    if not args.quiet and (args.placement == "processes" or not sys.stdout.isatty()):
        plain = PlainProgress(args.steps, start=ctx.start)
        stop = threading.Event()
        follower = follow_metrics(out / METRICS_FILE, plain, stop)
    signalled: list[int] = []
    try:
        if args.placement == "embedded":
            from .placements.launcher import quit_on_signals
            from .runtime.progress import watch_progress

            watchers = () if args.quiet or plain is not None else (watch_progress,)
            summary = run_embedded(ctx, tuple(args.listen), record=args.record,
                                   watchers=(*watchers, quit_on_signals(signalled)))
        else:
            from .placements.launcher import free_port

            port = free_port()
            print(f"router on tcp/127.0.0.1:{port} with authentication (qlap tui/record/echo "
                  f"--connect tcp/127.0.0.1:{port} --credentials {credentials})",
                  file=sys.stderr)
            summary = run_processes(ctx, port, record=args.record,
                                    **({} if groups is None else {"groups": groups}))
    finally:
        if plain is not None:
            stop.set()
            follower.join(5)
    if plain is not None:
        plain.final(summary)
    knowledge = json.loads((out / "knowledge.json").read_text())
    print(f"\n{summary['steps']} steps in {summary['wall_time_s']} s "
          f"({summary['steps_per_s']} steps/s); k = {summary.get('k')}, "
          f"{summary.get('dbns')} DBNs, {summary.get('plans')} plans, "
          f"{summary.get('landmarks')} landmarks, {summary.get('reliable_actions')} "
          f"sufficiently reliable actions; waits {summary['waits']}, rejected messages "
          f"{summary['rejected_messages']}, restarts {summary.get('restarts', 0)}")
    if args.clock == "realtime":
        print(f"realtime {summary.get('hz')} Hz: late ticks {summary.get('late_ticks')}, "
              f"missed ticks {summary.get('missed_ticks')}, lateness p50 "
              f"{summary.get('lateness_p50_ms')} ms, p99 {summary.get('lateness_p99_ms')} ms")
    from .analysis.show import format_knowledge

    print(format_knowledge(knowledge, limit=25))
    _print_written(out)
    if signalled:
        final = out / "checkpoints" / "final"
        go_on = (f" — go on from it: qlap run --resume {final} --out NEW_DIR"
                 if _resumes_exactly(final, summary["steps"]) else
                 " (checkpoints/final has a batch in flight)" + kept_checkpoint(out))
        print(f"qlap run: interrupted after {summary['steps']:,} steps; what was learned is "
              f"written{go_on}", file=sys.stderr)
        return 130
    return 0


def _resumes_exactly(checkpoint: Path, steps_done: int) -> bool:
    """Whether an actor placement's checkpoint after ``steps_done`` steps resumes exactly (no
    batch in flight, placements/resume.py)."""
    from .placements.resume import in_flight_problem
    from .qlap.checkpoint import CheckpointError, load_agent

    try:
        params = load_agent(checkpoint).learner.params
    except CheckpointError:
        return False
    return in_flight_problem(checkpoint, params, steps_done, "embedded") is None


def _cmd_actor(args: argparse.Namespace) -> int:
    import zenoh

    from .agent_run import params_for_world
    from .bus import keys
    from .bus.cli import client_from_args
    from .bus.config import BusConfigError
    from .placements.launcher import run_actor
    from .qlap import Params
    from .runtime.context import RunContext

    if args.credentials is not None:
        print(f"qlap actor: --credentials {args.credentials}: a run's credentials name its "
              "viewer, who may publish nothing; an actor connects as its own user (--user "
              "NAME with $QLAP_PASSWORD, docs/security.md)", file=sys.stderr)
        return 2
    world = _make_world(args.world, "actor")
    if world is None:
        return 2
    if (problem := lag_problem(args.lag)) is not None:
        print(f"qlap actor: {problem}", file=sys.stderr)
        world.close()
        return 2
    try:
        keys.validate_run_id(args.run)
        changes = {"batch_lag": args.lag}
        if args.babble_steps is not None:
            changes["babble_steps"] = args.babble_steps
        params = params_for_world(world, Params(**changes))
        config = client_from_args(args)
    except (ValueError, BusConfigError) as exc:
        print(f"qlap actor: {exc}", file=sys.stderr)
        return 2
    finally:
        world.close()
    ctx = RunContext(args.run, args.world, args.steps, args.seed, params, out=args.out)
    print(f"qlap actor {args.name}: run {args.run}, connecting to {', '.join(args.connect)}; "
          "then it waits until every actor of the run has joined (up to an hour; Ctrl-C to "
          "stop)", file=sys.stderr, flush=True)
    try:
        result = run_actor(args.name, ctx, config)
    except zenoh.ZError as exc:
        hint = "" if args.user else (" (a router with authentication needs the actor's own "
                                     "user: --user NAME with $QLAP_PASSWORD)")
        print(f"qlap actor: cannot connect to {', '.join(args.connect)}: {one_line(exc)}{hint}",
              file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"qlap actor {args.name}: stopped", file=sys.stderr)
        return 130
    print(json.dumps(result))
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from .analysis.runs import AnalysisError, load_knowledge

    try:
        knowledge = load_knowledge(args.path)
    except AnalysisError as exc:
        print(f"qlap show: {exc}", file=sys.stderr)
        return 2
    from .analysis.show import format_knowledge

    try:
        text = format_knowledge(knowledge, show_all=args.all)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        print(f"qlap show: {args.path}: malformed knowledge ({type(exc).__name__}: {exc})",
              file=sys.stderr)
        return 2
    print(text)
    return 0


def _world_mismatch(checkpoint: Path, world: Any, spec: str) -> str | None:
    """Why a checkpoint's agent cannot act in ``world`` (its variables are not the world's:
    it was learned in another world), or None (also when the checkpoint cannot be read:
    loading it says why)."""
    from .analysis.runs import recorded_world
    from .qlap.checkpoint import CheckpointError, resolve_checkpoint

    try:
        meta = json.loads((resolve_checkpoint(checkpoint) / "learner.json").read_text())
        names = [v["name"] for v in meta["variables"] if v.get("source", -1) == -1]
    except (OSError, ValueError, KeyError, TypeError, AttributeError, CheckpointError):
        return None
    if names == [v.name for v in world.variables]:
        return None
    learned = recorded_world(checkpoint)
    where = f"world {learned!r}" if learned else "another world"
    missing = [n for n in names if n not in {v.name for v in world.variables}]
    return (f"{checkpoint} was learned in {where}, not --world {spec!r}"
            + (f" (which has no {', '.join(missing[:3])}{', …' if len(missing) > 3 else ''})"
               if missing else " (its variables differ)"))


def _trace_problem(path: Path, policy: str) -> str | None:
    """Why ``qlap eval --trace path`` cannot be written, before any trial runs; None if it can."""
    if policy != "qlap":
        return "a trace needs --policy qlap"
    return _file_problem(path)


def _cmd_eval(args: argparse.Namespace) -> int:
    from .agent_run import evaluate
    from .qlap.checkpoint import CheckpointError

    if args.policy == "qlap" and args.checkpoint is None:
        print("qlap eval: --checkpoint is required with --policy qlap", file=sys.stderr)
        return 2
    if args.trace is not None:
        problem = _trace_problem(args.trace, args.policy)
        if problem is not None:
            print(f"qlap eval: --trace {args.trace}: {problem}", file=sys.stderr)
            return 2
    if args.world is None:            # the world the checkpoint was learned in
        from .analysis.runs import recorded_world

        recorded = recorded_world(args.checkpoint) if args.checkpoint is not None else None
        args.world = recorded or "core"
    world = _make_world(args.world, "eval")
    if world is None:
        return 2
    if args.policy == "qlap":
        mismatch = _world_mismatch(args.checkpoint, world, args.world)
        if mismatch is not None:
            print(f"qlap eval: {mismatch}", file=sys.stderr)
            world.close()
            return 2
    try:
        res = evaluate(args.checkpoint, world, args.task, args.trials, args.seed, args.policy,
                       pursue=args.goal, trace=args.trace)
    except (CheckpointError, ValueError, KeyError) as exc:
        reason = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"qlap eval: {reason}", file=sys.stderr)
        return 2
    except OSError as exc:                       # the trace could not be written
        print(f"qlap eval: --trace {args.trace}: cannot write ({exc.strerror or exc})",
              file=sys.stderr)
        return 1
    finally:
        world.close()
    if args.json:
        print(json.dumps(res))
    else:
        pursued = f", pursuing {res['pursued']}" if "pursued" in res else ""
        print(f"{res['world']} {res['task']} ({res['policy']}{pursued}, "
              f"{res['n_trials']} trial{'' if res['n_trials'] == 1 else 's'}): "
              f"mean reward {res['mean_reward']:.3f} ± {res['stderr_reward']:.3f} (s.e.), "
              f"success rate {res['success_rate']:.2f}")
        if "waiting_steps" in res:
            print(f"  a plan waited with the motors held in {res['waiting_steps']:,} of "
                  f"{res['policy_steps']:,} steps; trace: {args.trace}")
        if res.get("policy_steps") and res["steps_without_plan"] == res["policy_steps"]:
            goal = res.get("pursued", "the task's goal")
            print(f"  note: the agent had no plan for {goal} in any step: it moved randomly "
                  f"(or held still) in every trial, as a random policy would")
        elif res.get("steps_without_plan"):
            print(f"  without a plan for the goal: {res['steps_without_plan']:,} of "
                  f"{res['policy_steps']:,} steps (moving randomly meanwhile)")
        goals = res.get("by_goal", {})
        if len(goals) > 1:              # a task that draws its goal: each goal's trials
            for name, g in goals.items():
                trials = "trial " if g["trials"] == 1 else "trials"
                print(f"  {name:12s} {g['trials']:4d} {trials}: mean reward "
                      f"{g['mean_reward']:.3f}, {g['successes']} reached, {g['failures']} "
                      f"ended early, {g['timeouts']} timed out")
    return 0


def _cmd_analysis(args: argparse.Namespace) -> int:
    """``qlap curve`` and ``qlap report`` (qlap_runtime/analysis, docs/analysis.md)."""
    from .analysis import AnalysisError
    from .analysis.curve import main_curve
    from .analysis.report import main_report
    from .runtime.outputs import OutputError, check_out

    try:
        if args.command == "curve" and args.out is not None:
            check_out(args.out, min_free=2**20)     # before the evaluations, not after
        if args.command == "curve":
            from .runtime.interrupt import interrupt_on_signals

            with interrupt_on_signals():
                return main_curve(args.runs, args.task, args.trials, args.jobs, args.seed,
                                  args.out, args.world, echo=lambda s: print(s, flush=True),
                                  every=args.every, at=args.at)
        print(main_report(args.runs, as_json=args.json))
    except (AnalysisError, OutputError) as exc:
        print(f"qlap {args.command}: {exc}", file=sys.stderr)
        return 2
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    """``qlap plot``: each run's metrics log (and curve.csv) to RUN_DIR/metrics.png."""
    from .analysis import AnalysisError
    from .analysis.plot import plot_run

    status = 0
    for run_dir in args.runs:
        try:
            print(f"wrote {plot_run(run_dir)}")
        except AnalysisError as exc:
            print(f"qlap plot: {exc}", file=sys.stderr)
            status = 2
    return status


if __name__ == "__main__":
    sys.exit(main())
