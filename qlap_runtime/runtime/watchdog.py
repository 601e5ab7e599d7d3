"""No silent hang: every lockstep wait reports itself on a progress board, and a watchdog stops a
run that makes no progress with one line naming the actor and the step it waits for
(docs/runtime.md, Faults).

Each actor owns a :class:`Slot` — a few numbers in shared memory (processes placement: a
``multiprocessing`` raw array created by the supervisor and handed to every incarnation of the
actor's process) or in this process (embedded) — holding the last step it finished, what it
waits for (topic and step) and at which step, whether a batch of its own is being computed and
whether it is paused (the world, by a ``pause``, ``step`` or ``speed`` control). A write is a
store into an array of doubles: the step chain pays a few hundred nanoseconds.

:class:`Watchdog` looks at the board: when no actor has finished a step for ``stall_s`` seconds
while at least one waits in the lockstep, none computes a batch and the world is not paused or
paced, and some actor has finished a step (start-up has its own time limit), the run is
stalled and :meth:`Watchdog.check` raises :class:`RunStalled`, e.g.
``run stalled: no progress for 30 s; contingency waits for batchctx(5999) at step 6000;
executor waits for delta/dbn(6000) at step 6200``. The supervisor checks it at every poll
(and restarts reset the clock); the embedded placement runs it as a trio task.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from ..errors import ActorFailed

DEFAULT_STALL_S = 30.0
"""Seconds without progress after which a run is stalled (``RunContext.stall_s``)."""

TOPICS = ("", "sense", "qstate", "motor", "batchctx", "delta/dbn", "delta/landmarks",
          "control")
"""What an actor can wait for (index = the code stored in its slot)."""

DONE, TOPIC, WAIT_STEP, AT_STEP, BUSY, PAUSED, FINISHED = range(7)
SIZE = 7


class RunStalled(ActorFailed):
    """The run made no progress for ``stall_s`` seconds although an actor waits for a step."""


class Slot:
    """One actor's line on the board (``data``: any mutable sequence of ``SIZE`` floats)."""

    def __init__(self, data: Any | None = None) -> None:
        self.data = data if data is not None else [0.0] * SIZE
        self.data[DONE] = -1.0

    def done(self, step: int) -> None:
        """The actor finished ``step``."""
        self.data[DONE] = step

    def wait(self, topic: str, step: int, at: int | None = None) -> None:
        """The actor now waits for ``topic``'s message of ``step`` (before passing ``at``)."""
        d = self.data
        d[WAIT_STEP] = step
        d[AT_STEP] = step if at is None else at
        d[TOPIC] = TOPICS.index(topic) if topic in TOPICS else 0

    def clear(self) -> None:
        self.data[TOPIC] = 0

    @contextmanager
    def waiting(self, topic: str, step: int, at: int | None = None) -> Iterator[None]:
        self.wait(topic, step, at)
        try:
            yield
        finally:
            self.clear()

    def busy(self, n: int) -> None:
        """How many batches of this actor are being computed (no progress is expected)."""
        self.data[BUSY] = n

    def paused(self, flag: bool) -> None:
        self.data[PAUSED] = 1.0 if flag else 0.0

    def finished(self) -> None:
        """The actor's step loop is over (it may still write its outputs)."""
        self.data[TOPIC] = 0
        self.data[FINISHED] = 1.0

    def restarted(self) -> None:
        """A new incarnation of the actor starts (the supervisor's side)."""
        self.data[TOPIC] = 0
        self.data[FINISHED] = 0.0
        self.data[BUSY] = 0.0

    def waits_for(self) -> tuple[str, int, int] | None:
        code = int(self.data[TOPIC])
        if not code or self.data[FINISHED]:
            return None
        return TOPICS[code], int(self.data[WAIT_STEP]), int(self.data[AT_STEP])


class Board:
    """The slots of a run's actors (``slots``: name -> shared data, or None for in-process)."""

    def __init__(self, names: tuple[str, ...] | list[str],
                 slots: dict[str, Any] | None = None) -> None:
        self.slots = {n: Slot(None if slots is None else slots[n]) for n in names}
        self.stalled: str | None = None
        """Set (the one-line reason) when the watchdog stops the run: the actors of an
        embedded run that are cancelled then keep what was learned (a final checkpoint)."""

    def slot(self, name: str) -> Slot:
        return self.slots.setdefault(name, Slot())


def slot_of(ctx: Any, name: str) -> Slot:
    """The actor's slot on ``ctx.board`` (a throw-away one when the run has no board)."""
    board = getattr(ctx, "board", None)
    return board.slot(name) if board is not None else Slot()


class Watchdog:
    """Detects a run that makes no progress (see the module docstring)."""

    def __init__(self, board: Board, stall_s: float = DEFAULT_STALL_S,
                 clock: Any = time.monotonic) -> None:
        self.board, self.stall_s, self.clock = board, float(stall_s), clock
        self.last_change = clock()
        self._sig: tuple = ()

    def reset(self) -> None:
        """Something happened that explains a pause in progress (a restart)."""
        self.last_change = self.clock()

    def check(self) -> None:
        """Raise :class:`RunStalled` if the run is stalled."""
        now = self.clock()
        slots = self.board.slots
        sig = tuple(s.data[DONE] for s in slots.values())
        busy = any(s.data[BUSY] > 0 and not s.data[FINISHED] for s in slots.values())
        paused = any(s.data[PAUSED] > 0 and not s.data[FINISHED] for s in slots.values())
        if max(sig, default=-1.0) < 0:
            # Nothing stepped yet (processes spawning, sessions opening): the world's wait for
            # the other actors has its own time limit.
            self.last_change = now
            return
        if sig != self._sig or busy or paused:
            self._sig, self.last_change = sig, now
            return
        idle = now - self.last_change
        if idle < self.stall_s:
            return
        waits = sorted(((w, name) for name, s in slots.items()
                        if (w := s.waits_for()) is not None), key=lambda x: (x[0][1], x[1]))
        if not waits:
            return
        parts = [f"{name} waits for {topic}({step}) at step {at}"
                 for (topic, step, at), name in waits]
        self.board.stalled = f"run stalled: no progress for {idle:.0f} s; " + "; ".join(parts)
        raise RunStalled(self.board.stalled)
