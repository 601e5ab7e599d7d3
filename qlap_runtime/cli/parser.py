"""The parser of the ``qlap`` command line: :func:`build_parser` builds it with every
subcommand's options and help; :class:`Parser` makes its errors one line naming the command,
:class:`HelpFormatter` appends each option's default to its help, :func:`endpoint_arg` checks a
Zenoh endpoint as an argument type, and ``_version`` is what ``qlap --version`` prints."""

from __future__ import annotations

import argparse
from typing import NoReturn

from ..argtypes import Once, count, goal_arg, path_arg, positive_float, positive_int


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

    from .. import __version__

    try:
        return version("qlap-runtime")
    except PackageNotFoundError:        # a source tree that was not installed
        return __version__


def endpoint_arg(text: str) -> str:
    """A Zenoh endpoint ``PROTOCOL/HOST:PORT``, checked before the run starts."""
    from ..bus.config import BusConfigError, validate_endpoint

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
                          "and keeps what was learned); with --resume, the steps after the "
                          "checkpoint's: step-0200000 with --steps 50000 ends at step 250,000")
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
    ev.add_argument("--goal", type=goal_arg, default=None, metavar="VAR=VALUE", action=Once,
                    help="the agent pursues this goal in every trial instead of the task's "
                         "(e.g. T_L.dot=+ in hit_floor: how often pushing the block left "
                         "knocks it off); the task still judges each trial")
    ev.add_argument("--trace", type=path_arg, default=None, metavar="FILE.jsonl",
                    help="write every step of the trials as JSON lines: the goal, the agent's "
                         "mode and call list, whether a plan waits with the motors held, "
                         "the motor command; then each trial's reward (docs/analysis.md); a "
                         "new file, never overwritten")
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
                      help="PNG file to write (its directory must exist; an existing file "
                           "is replaced)")
    snap.add_argument("--seed", type=count, default=0, help="seed of the world's placement")

    from ..experiments.cli import add_experiment_command

    add_experiment_command(sub)

    from ..bus.cli import add_bus_commands

    add_bus_commands(sub)

    actor = sub.add_parser(
        "actor", help="run one actor of a distributed run (connects to a router)",
        description="Run one actor (world, perception, contingency, landmarks, planner, executor) "
                    "on this machine, connected to a Zenoh router (qlap router). Start every "
                    "actor of the run with the same --run, --world, --steps, --seed and "
                    "learning options; the world starts stepping when the others are alive.")
    actor.add_argument("name", choices=("world", "perception", "contingency", "landmarks",
                                        "planner", "executor"), help="the actor to run here")
    from ..bus.cli import connection_args

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
                       help="(executor) where to write knowledge.json, checkpoints: a new "
                            "directory (one holding a run is refused)")

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
