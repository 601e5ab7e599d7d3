"""The ``qlap actor`` command: one actor of a distributed run in this process,
connected to a Zenoh router with the actor's own user (docs/security.md)."""

from __future__ import annotations

import argparse
import json
import sys

from ..errors import one_line
from .common import lag_problem, make_world


def cmd_actor(args: argparse.Namespace) -> int:
    import zenoh

    from ..agent_run import params_for_world
    from ..bus import keys
    from ..bus.cli import client_from_args
    from ..bus.config import BusConfigError
    from ..placements.launcher import run_actor
    from ..qlap import Params
    from ..runtime.context import RunContext

    if args.credentials is not None:
        print(f"qlap actor: --credentials {args.credentials}: a run's credentials name its "
              "viewer, who may publish nothing; an actor connects as its own user (--user "
              "NAME with $QLAP_PASSWORD, docs/security.md)", file=sys.stderr)
        return 2
    world = make_world(args.world, "actor")
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
    if args.name == "executor" and args.out is not None:
        # The executor writes the run's outputs (metrics, knowledge, checkpoints): never
        # into another run's directory, whose files it would truncate or replace.
        from .run_dir import out_refused

        if (problem := out_refused(args.out)) is not None:
            print(f"qlap actor: {problem}", file=sys.stderr)
            return 2
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
