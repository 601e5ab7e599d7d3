"""The ``qlap tui`` command: the terminal UI attached to a run reachable through a
Zenoh endpoint (``qlap run --listen`` or a router), once the endpoint answers."""

from __future__ import annotations

import argparse

from ..errors import CliError, one_line


def cmd_tui(args: argparse.Namespace) -> int:
    """``qlap tui --connect``: the UI on a remote run, once the endpoint answers."""
    import zenoh

    from tui import QlapApp

    from ..bus.auth import UI_USER
    from ..bus.cli import connect_failure, credentials_for
    from ..bus.config import client_config

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
