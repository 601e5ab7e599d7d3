"""The QLAP terminal UI (docs/tui.md): a Textual app that only talks to the bus.

- :class:`QlapApp` — the UI: subscribes to a run's telemetry, publishes ``control``.
- :class:`LocalDriver` — the synchronous agent in a thread on an embedded Zenoh session,
  publishing the telemetry the UI shows (``qlap run`` in a terminal).
- :func:`run_local` — both together; :func:`attach` — the UI on a remote run
  (``qlap tui --connect``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .app import BusFeed, QlapApp
from .driver import LocalDriver

__all__ = ["BusFeed", "LocalDriver", "QlapApp", "attach", "run_local"]


def run_local(driver: LocalDriver) -> LocalDriver:
    """Start ``driver`` (if not started), run the UI in this terminal until the user quits,
    then stop the driver and close its session. Returns the driver (its agent is still there)."""
    if not driver.alive:
        driver.start()
    try:
        QlapApp(driver=driver).run()
    finally:
        driver.stop()
    return driver


def attach(connect: Sequence[str] | str, run_id: str | None = None, **client: Any) -> None:
    """Run the UI on a remote run through a router (``client_config(connect, **client)``)."""
    QlapApp(connect=connect, run_id=run_id, **client).run()
