"""The ``qlap run`` command: :func:`cmd_run` checks that the flags go together and
settles the world, seed, placement and lag (a resumed agent keeps its checkpoint's), then hands
the run to the sync loop, the actor placements or the terminal UI (run_placements.py); a run
stopped by a failed write says which checkpoint it keeps (:func:`stopped_run_tail`)."""

from __future__ import annotations

import argparse
import sys

from .common import lag_problem, make_world, world_mismatch
from .run_dir import kept_checkpoint
from .run_placements import run_actors, run_sync, run_tui

DEFAULT_ACTOR_LAG = 500
"""Default batch lag L of the actor placements (docs/architecture.md §2: batches pipelined, the
step chain never waits for them); the synchronous loop defaults to L = 0, Algorithm 2 to the
letter."""


def cmd_run(args: argparse.Namespace) -> int:
    try:
        return _cmd_run_inner(args)
    except OSError as exc:               # e.g. the disk filled up during the run
        print(f"qlap run: {exc}" + stopped_run_tail(args, exc), file=sys.stderr)
        return 1


def stopped_run_tail(args: argparse.Namespace, exc: BaseException) -> str:
    """What follows the error of a stopped run: its directory (for a failed write) and the
    checkpoint it keeps."""
    where = getattr(args, "run_dir", None)
    return ((f" (run directory {where})" if where and isinstance(exc, OSError) else "")
            + kept_checkpoint(where))


def run_stopped(exc: BaseException) -> bool:
    """A run an actor placement stopped: a write failed (OSError) or an actor could not be
    restarted (``ActorFailed``)."""
    from ..errors import ActorFailed

    return isinstance(exc, OSError | ActorFailed)


def _cmd_run_inner(args: argparse.Namespace) -> int:
    from ..qlap import Params
    from ..qlap.checkpoint import checkpoint_seed

    if args.world is None:            # a resumed agent goes on in the world it learned in
        from ..analysis.runs import recorded_world

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
    world = make_world(args.world, "run")
    if world is None:
        return 2
    if args.resume is not None and (
            mismatch := world_mismatch(args.resume, world, args.world)) is not None:
        print(f"qlap run: --resume: {mismatch}", file=sys.stderr)
        world.close()
        return 2
    if tui:
        world.close()                       # made to check the spec; the UI's agent makes its own
        return run_tui(args)
    if args.placement != "sync":
        return run_actors(args, world, params)
    try:
        return run_sync(args, world, params)
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
