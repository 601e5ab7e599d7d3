"""Ctrl-C and SIGTERM as a request to stop between two steps (docs/runtime.md, "Stopping").

A run told to stop by a signal ends the way it ends after its last step: the outputs of what
was learned are written (knowledge.json, summary.json, checkpoints/final), so that it can go on
with ``--resume``. A second Ctrl-C interrupts at once, for a run that does not stop. A signal
that is ignored when the run starts stays ignored (:func:`heeded`): ``nohup``'s SIGHUP, a
command started with ``&`` from a script (its SIGINT).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["STOP_SIGNALS", "heeded", "interrupt_on_signals", "stop_on_signals"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Ctrl-C, ``kill``, and the terminal closing."""


def heeded(signals: tuple[signal.Signals, ...]) -> tuple[signal.Signals, ...]:
    """The ``signals`` not ignored now: a process started under ``nohup`` (SIGHUP ignored) or with
    ``&`` from a script (SIGINT ignored) keeps them ignored, as programs do by convention
    (Python itself installs its Ctrl-C handler only where SIGINT is not ignored)."""
    return tuple(s for s in signals if signal.getsignal(s) is not signal.SIG_IGN)


@contextmanager
def stop_on_signals(signals: tuple[signal.Signals, ...] = STOP_SIGNALS
                    ) -> Iterator[threading.Event]:
    """While the block runs, the first of ``signals`` sets the event it yields (the loop checks
    it between steps); a Ctrl-C after that raises KeyboardInterrupt. The previous handlers
    come back after the block. Main thread only (Python's rule for signal handlers)."""
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:
        if stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop.set()

    previous = {s: signal.signal(s, handler) for s in heeded(signals)}
    try:
        yield stop
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def interrupt_on_signals(signals: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGHUP)
                         ) -> Iterator[None]:
    """While the block runs, SIGTERM and SIGHUP raise KeyboardInterrupt as Ctrl-C does, so that
    the block's cleanup runs (a pool's worker processes stopped, not orphaned). Main thread
    only."""
    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, handler) for s in heeded(signals)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
