"""Writes off the step chain: one job at a time in a thread of its own (docs/decisions.md 81).

The executor's periodic checkpoint (``save_step_checkpoint``: JSON, npz and the lzma of the
histories, then the retention) took about 0.5 s on the step chain for a 30,000-step core
agent; it now writes a deep copy of the agent in such a thread (the copy, ~0.1 s, on the
chain), most of it with the GIL released (lzma, ``fsync``). :meth:`Background.wait` joins the
job in flight and raises its error, before the next job and before the run's final files.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class Background:
    """At most one job at a time; its error is raised by the next :meth:`start` or
    :meth:`wait`."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.thread: threading.Thread | None = None
        self.error: BaseException | None = None

    def start(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` in a thread once the job before it is done."""
        self.wait()
        self.thread = threading.Thread(target=self._run, args=(fn, args), name=self.name,
                                       daemon=True)
        self.thread.start()

    def _run(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            fn(*args)
        except BaseException as exc:            # raised in the caller's thread by wait()
            self.error = exc

    def wait(self) -> None:
        """Join the job in flight; raise its error."""
        if self.thread is not None:
            self.thread.join()
            self.thread = None
        error, self.error = self.error, None
        if error is not None:
            raise error
