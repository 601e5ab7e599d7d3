"""``python -m tui``: the UI until ``qlap run`` / ``qlap tui`` are wired (docs/tui.md).

    python -m tui run --world core2d [--steps N] [--seed S] [--babble-steps B] [--listen EP]
    python -m tui connect tcp/127.0.0.1:7447 [--run RUN]
"""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tui")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="a local agent with the UI")
    r.add_argument("--world", default="core2d")
    r.add_argument("--steps", type=int, default=None)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--babble-steps", type=int, default=None)
    r.add_argument("--fast", action="store_true",
                   help="short babbling and batch periods, so plans appear within seconds")
    r.add_argument("--listen", action="append", default=[])
    r.add_argument("--run", default=None)
    r.add_argument("--checkpoints", default="qlap-checkpoints")
    c = sub.add_parser("connect", help="attach to a running agent through a router")
    c.add_argument("endpoint", nargs="+")
    c.add_argument("--run", default=None)
    args = p.parse_args(argv)
    if args.cmd == "connect":
        from . import attach

        attach(args.endpoint, args.run)
        return 0
    from . import DriverProcess, run_process

    params: dict = {}
    if args.fast:
        params.update(babble_steps=2000, dbn_period=500, landmark_period=1000)
    if args.babble_steps is not None:
        params["babble_steps"] = args.babble_steps
    proc = DriverProcess(args.world, params=params, seed=args.seed, steps=args.steps,
                         listen=args.listen, run_id=args.run, checkpoint_dir=args.checkpoints)
    run_process(proc)
    return 0 if proc.exitcode in (0, None) else 1

if __name__ == "__main__":
    sys.exit(main())
