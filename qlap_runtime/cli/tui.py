"""The ``qlap tui`` command: the terminal UI attached to a run reachable through a
Zenoh endpoint (``qlap run --listen`` or a router), once the endpoint answers."""

from __future__ import annotations

import argparse

from ..errors import CliError, one_line


def cmd_tui(args: argparse.Namespace) -> int:
    """``qlap tui --connect``: the UI on a remote run, once the endpoint answers."""
    import zenoh

    from tui import QlapApp

    from ..bus import keys
    from ..bus.auth import UI_USER
    from ..bus.cli import connect_failure, credentials_for
    from ..bus.config import BusConfigError, client_config

    if args.run is not None:                    # wrong values before any connection
        try:
            keys.validate_run_id(args.run)
        except ValueError as exc:
            raise CliError(f"--run {args.run}: {exc}") from None
    user, password = credentials_for(args.credentials, UI_USER)
    auth = {"user": user, "password": password} if user else {}
    try:
        config = client_config(args.connect, **auth)
    except BusConfigError as exc:               # a malformed endpoint: exit 2, as echo's
        raise CliError(str(exc)) from None
    try:
        zenoh.open(config).close()
    except zenoh.ZError as exc:
        raise CliError(connect_failure(args.connect, one_line(exc), args.credentials),
                       code=1) from None
    try:
        app = QlapApp(connect=args.connect, run_id=args.run, **auth)
    except ValueError as exc:
        raise CliError(f"--run {args.run}: {exc}") from None
    app.run()
    return 0 if app.return_code in (0, None) else 1
