"""The QLAP terminal UI (docs/tui.md): a Textual app that only talks to the bus.

- :class:`QlapApp` — the UI: subscribes to a run's telemetry, publishes ``control``.
- :class:`LocalDriver` — the synchronous agent in a thread on an embedded Zenoh session,
  publishing the telemetry the UI shows (``qlap run`` in a terminal).
- :func:`run_local` — both together; ``QlapApp(connect=..., run_id=...)`` — the UI on a
  remote run (``qlap tui --connect``).
"""

from __future__ import annotations

import signal

from .app import BusFeed, QlapApp
from .driver import DriverProcess, LocalDriver

__all__ = ["BusFeed", "DriverProcess", "LocalDriver", "QlapApp", "run_local", "run_process"]


def run_local(driver: LocalDriver) -> LocalDriver:
    """Start ``driver`` (if not started) in a thread of this process, run the UI until the user
    quits, then stop the driver and close its session. Simple, but the UI shares the GIL with
    the agent (about 4x slower, docs/tui.md): prefer :func:`run_process`."""
    if not driver.alive:
        driver.start()
    try:
        QlapApp(driver=driver).run()
    finally:
        driver.stop()
    return driver


def run_process(proc: DriverProcess) -> DriverProcess:
    """``qlap run`` in a terminal: the agent in its own process (:class:`DriverProcess`), the
    UI here connected to it on loopback; quitting the UI stops the agent."""
    if proc.exitcode is None and not proc.alive:
        proc.start()
    # SIGTERM or the terminal closing (SIGHUP) end the UI as its `q` does: the agent is told
    # to quit and writes its outputs (and the terminal is restored).
    app = QlapApp(connect=proc.endpoint, run_id=proc.run_id, quit_on=(signal.SIGTERM,
                                                                      signal.SIGHUP),
                  **proc.client)
    try:
        app.run()
    finally:
        if proc.alive and not app.run_finished:    # quit mid-run: the agent saves first
            try:
                print("stopping the agent: it writes its final checkpoint and outputs …",
                      flush=True)
            except OSError:                        # the terminal is gone (SIGHUP)
                pass
        proc.stop()
    return proc
