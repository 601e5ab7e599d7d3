"""``qlap router``, ``qlap record`` and ``qlap echo``: the bus subcommands.

Wire into the main parser with::

    from qlap_runtime.bus.cli import add_bus_commands, run_bus_command, BUS_COMMANDS
    add_bus_commands(sub)                      # sub = parser.add_subparsers(...)
    if args.command in BUS_COMMANDS:
        return run_bus_command(args)

Each command runs until done or until SIGINT/SIGTERM, then closes its session and exits 0
(2 for a configuration error, 1 when the router cannot be reached).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from collections.abc import Awaitable, Callable
from functools import partial
from pathlib import Path
from typing import Any

import trio
import zenoh

from ..argtypes import non_negative_float, positive_float, positive_int
from ..errors import one_line
from .auth import VIEWER
from .config import BusConfigError, TlsFiles, client_config, config_from_file, router_config

BUS_COMMANDS = ("router", "record", "echo")


def connection_args(p: argparse.ArgumentParser) -> None:
    """Add the options that connect a client to a router (``--connect``, credentials, TLS)."""
    p.add_argument("--connect", action="append", required=True, metavar="ENDPOINT",
                   help="router endpoint, e.g. tcp/127.0.0.1:7447 or tls/host:7447 "
                        "(repeatable)")
    p.add_argument("--user", default=None, help="user name (usrpwd authentication)")
    p.add_argument("--password", default=os.environ.get("QLAP_PASSWORD"),
                   help="password (default: $QLAP_PASSWORD)")
    p.add_argument("--credentials", type=Path, default=None, metavar="FILE",
                   help="a run's bus-credentials.json (its viewer user; default: "
                        "$QLAP_CREDENTIALS), instead of --user/--password")
    p.add_argument("--tls-ca", type=Path, default=None, help="CA certificate for tls/ endpoints")
    p.add_argument("--tls-cert", type=Path, default=None, help="client certificate (mutual TLS)")
    p.add_argument("--tls-key", type=Path, default=None, help="client key (mutual TLS)")


def add_bus_commands(sub: Any) -> None:
    """Add ``router``, ``record`` and ``echo`` to a subparsers object (what
    ``ArgumentParser.add_subparsers`` returns; argparse names its type only privately)."""
    r = sub.add_parser("router", help="run a Zenoh router for distributed actors",
                       description="Run a Zenoh router (mode router, no scouting) until "
                                   "Ctrl-C. Either --config FILE (JSON5, see "
                                   "examples/router.json5) or --listen ENDPOINT.")
    r.add_argument("--config", type=Path, default=None,
                   help="zenoh JSON5 config file (default: a router on --listen)")
    r.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on (default tcp/127.0.0.1:7447; repeatable)")

    rec = sub.add_parser("record", help="record a running agent's bus to an MCAP file",
                         description="Subscribe to qlap/<run>/** and write every message to an "
                                     "MCAP file that opens in Foxglove: topics /qlap/<topic> "
                                     "(JSON with JSON Schemas), a qlap.run metadata record per "
                                     "run, and the world's bodies on /qlap/scene "
                                     "(foxglove.SceneUpdate) for the 3D panel.")
    connection_args(rec)
    rec.add_argument("--out", type=Path, required=True, help="output .mcap file")
    rec.add_argument("--run", default=None, help="run id to record (default: every run)")
    rec.add_argument("--duration", type=positive_float, default=None,
                     help="stop after this many seconds (default: until Ctrl-C)")
    rec.add_argument("--scene-hz", type=non_negative_float, default=30.0, metavar="HZ",
                     help="scene updates on /qlap/scene per second, drawn from the sense "
                          "messages (0: one per step; default: %(default)s)")
    rec.add_argument("--no-scene", action="store_true", help="record no /qlap/scene")

    e = sub.add_parser("echo", help="print the messages on a key expression",
                       description="Print KEY JSON lines for every message on KEY "
                                   "(e.g. 'qlap/**' or 'qlap/RUN/sense').")
    connection_args(e)
    e.add_argument("key", metavar="KEY", help="key expression")
    e.add_argument("--count", type=positive_int, default=None, metavar="N",
                   help="stop after N messages (default: until Ctrl-C)")
    e.add_argument("--raw", action="store_true", help="print payloads without validating")


def run_bus_command(args: argparse.Namespace) -> int:
    """Run a parsed ``router`` / ``record`` / ``echo`` command; return the exit code."""
    try:
        if args.command == "router":
            cfg = (config_from_file(args.config) if args.config is not None
                   else router_config(args.listen or ["tcp/127.0.0.1:7447"]))
            return trio.run(_router, cfg)
        if args.command == "echo":
            key_problem = _key_problem(args.key)
            if key_problem is not None:
                print(f"qlap echo: KEY {args.key!r}: {key_problem}", file=sys.stderr)
                return 2
        cfg = client_from_args(args)
        if args.command == "record":
            return trio.run(_record, cfg, args)
        if args.command == "echo":
            return trio.run(_echo, cfg, args)
    except BusConfigError as e:
        print(f"qlap {args.command}: {e}", file=sys.stderr)
        return 2
    except Exception as e:             # also inside trio's exception groups
        leaf = _expected(e)
        if leaf is None:
            raise
        print(f"qlap {args.command}: {_describe(leaf, args)}", file=sys.stderr)
        return 2 if isinstance(leaf, BusConfigError) else 1
    raise ValueError(f"not a bus command: {args.command!r}")


def _key_problem(key: str) -> str | None:
    """Why ``key`` is not a Zenoh key expression (checked before connecting), or None."""
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError as exc:
        reason = one_line(exc)
        return "not a key expression" + (f" ({reason.split(': ', 1)[-1]})"
                                         if ": " in reason else "")
    return None


def _expected(exc: BaseException) -> BaseException | None:
    """``exc`` itself, or the first error of an exception group whose errors are all expected
    (an unreachable endpoint, a file that cannot be written, a bad configuration)."""
    if isinstance(exc, BaseExceptionGroup):
        leaves = [_expected(e) for e in exc.exceptions]
        return leaves[0] if leaves and all(leaf is not None for leaf in leaves) else None
    return exc if isinstance(exc, zenoh.ZError | OSError | BusConfigError) else None


def _describe(exc: BaseException, args: argparse.Namespace) -> str:
    """One line: 'cannot connect to ENDPOINTS: …' for Zenoh, 'FILE: reason' for a file."""
    text = one_line(exc)
    if isinstance(exc, zenoh.ZError) and getattr(args, "connect", None):
        return connect_failure(args.connect, text, getattr(args, "credentials", None))
    if isinstance(exc, zenoh.ZError) and args.command == "router":
        if args.config is None:
            return f"cannot listen on {', '.join(args.listen or ['tcp/127.0.0.1:7447'])}: {text}"
        return f"--config {args.config}: {text}{_dictionary_hint(args.config, text)}"
    return text


def _dictionary_hint(config: Path, text: str) -> str:
    """Which users file a router config's failure is about (Zenoh does not name it)."""
    if "dictionary file" not in text:
        return ""
    try:
        name = json.loads(config_from_file(config).get_json(
            "transport/auth/usrpwd/dictionary_file"))
    except Exception:                   # the hint is a courtesy: the error stands without it
        return ""
    return f" (its usrpwd dictionary_file {name!r}, from {Path.cwd()})"


def connect_failure(endpoints: list[str], reason: str, credentials: Path | None) -> str:
    """'cannot connect to ENDPOINTS: reason', with a hint when no credentials were given at
    all: every endpoint a run opens requires them (docs/security.md)."""
    from .auth import credentials_from_env

    hint = "" if credentials is not None or credentials_from_env(None) is not None else \
        " (an endpoint a run opens needs --credentials RUN_DIR/bus-credentials.json)"
    return f"cannot connect to {', '.join(endpoints)}: {reason}{hint}"


def client_from_args(args: argparse.Namespace) -> zenoh.Config:
    """The client configuration that :func:`connection_args`'s options ask for."""
    tls = None
    if args.tls_ca is not None or args.tls_cert is not None:
        tls = TlsFiles(ca=args.tls_ca, certificate=args.tls_cert, private_key=args.tls_key,
                       mtls=args.tls_cert is not None)
    user, password = args.user, args.password if args.user else None
    if user is None:
        user, password = credentials_for(getattr(args, "credentials", None), VIEWER)
    return client_config(args.connect, tls=tls, user=user, password=password)


def credentials_for(path: Path | None, user: str) -> tuple[str | None, str | None]:
    """(user, password) from ``--credentials`` or ``$QLAP_CREDENTIALS`` (none: (None, None))."""
    from .auth import credentials_from_env, read_credentials

    found = credentials_from_env(path)
    if found is None:
        return None, None
    name, password, _ = read_credentials(found, user)
    return name, password


async def _until_signal(stop: trio.Event, *, task_status: trio.TaskStatus[None]) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
        task_status.started()
        async for _ in signals:
            stop.set()
            return


async def serve_router(cfg: zenoh.Config, stop_event: trio.Event, *,
                       task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
    """Hold a router session open until ``stop_event`` is set (the launcher's in-process
    router for the ``processes`` placement, or ``qlap router``)."""
    with zenoh.open(cfg):
        task_status.started()
        await stop_event.wait()


async def _router(cfg: zenoh.Config) -> int:
    stop = trio.Event()
    async with trio.open_nursery() as nursery:
        await nursery.start(_until_signal, stop)
        await nursery.start(serve_router, cfg, stop)
        print(f"qlap router: listening on {cfg.get_json('listen/endpoints')}; Ctrl-C to stop",
              file=sys.stderr)
    return 0


async def _announced(command: Callable[..., Awaitable[Any]], line: str) -> Any:
    """Run ``command(task_status=...)`` to its end, printing ``line`` on stderr once it says
    it is subscribed (what is published from then on reaches it); its result."""
    result: list[Any] = []

    async def run(task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
        result.append(await command(task_status=task_status))

    async with trio.open_nursery() as nursery:
        await nursery.start(run)
        print(line, file=sys.stderr, flush=True)
    return result[0]


async def _record(cfg: zenoh.Config, args: argparse.Namespace) -> int:
    from .recorder import record

    stop = trio.Event()
    async with trio.open_nursery() as nursery:
        await nursery.start(_until_signal, stop)
        if args.duration is not None:
            async def timer() -> None:
                await trio.sleep(args.duration)
                stop.set()
            nursery.start_soon(timer)
        summary = await _announced(
            partial(record, cfg, args.run, args.out, stop,
                    scene_hz=None if args.no_scene else max(args.scene_hz, 0.0)),
            f"qlap record: recording {args.run or 'every run'} to {args.out}; "
            + (f"stops after {args.duration:g} s or at Ctrl-C" if args.duration is not None
               else "Ctrl-C to stop"))
        nursery.cancel_scope.cancel()
    if summary.error:
        print(f"qlap record: --out {args.out}: the recording stopped after {summary.messages:,} "
              f"messages ({summary.error}); they are in {args.out}.part", file=sys.stderr)
        return 1
    print(f"qlap record: {summary.messages} messages on {len(summary.by_topic)} topics and "
          f"{summary.scenes} scene updates of {len(summary.runs)} run(s) to {summary.path} "
          f"({summary.rejected} rejected)", file=sys.stderr)
    return 0


async def _echo(cfg: zenoh.Config, args: argparse.Namespace) -> int:
    from .recorder import echo

    stop = trio.Event()
    async with trio.open_nursery() as nursery:
        await nursery.start(_until_signal, stop)

        await _announced(partial(echo, cfg, args.key, stop, raw=args.raw, limit=args.count),
                         f"qlap echo: printing {args.key}; Ctrl-C to stop")
        nursery.cancel_scope.cancel()
    return 0


def main(argv: list[str] | None = None) -> int:
    """Standalone entry point: ``python -m qlap_runtime.bus.cli router|record|echo ...``."""
    p = argparse.ArgumentParser(prog="qlap-bus")
    add_bus_commands(p.add_subparsers(dest="command", required=True))
    return run_bus_command(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
