"""The run's ``control`` topic and the clock commands (docs/runtime.md, Controls).

:class:`Controls` delivers ``qlap/<run>/control`` on an actor's trio loop (decoded there, a
malformed message counted) and carries the world's end marker; :class:`RunControl` is the
state the clock commands (``pause``, ``resume``, ``step``, ``speed``, ``quit``) set, obeyed by
the world actor and by the terminal UI's local runner, and mirrored by the executor for its
status. The agent commands (``goal``, ``save``) are :mod:`.runner`'s.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import trio

from ..bus import keys
from ..bus.bridge import RejectionCounter
from ..bus.schema import Control
from .context import RunContext

log = logging.getLogger("qlap.actors")


class ControlError(ValueError):
    """A control command whose arguments are malformed (counted as a rejected message)."""


class Controls:
    """The run's ``control`` topic (``qlap/<run>/control``), delivered on the actor's trio loop.

    The Zenoh callback only schedules :meth:`_deliver` with ``run_sync_soon`` (thread-safe, in
    arrival order); decoding happens there, on the trio thread, where a malformed message is
    counted by the actor's :class:`RejectionCounter` and dropped. Controls of another run never
    arrive: the key carries the run id. Create inside trio.

    - ``pending`` / :meth:`take` / :meth:`wait`: the commands, for the actors that obey them
      (world, executor); ``keep=False`` keeps none (the other actors only need the end).
    - The world's end marker, ``quit {"last_step": T}``, sets :attr:`last_step` and interrupts
      every :meth:`interruptible` wait (a :class:`StepInbox` waiting for a step after T), so
      that every actor finishes its loop after step T and writes its outputs.
    """

    def __init__(self, session: Any, ctx: RunContext, counter: RejectionCounter,
                 keep: bool = True) -> None:
        self.key = keys.key(ctx.run_id, "control")
        self.counter = counter
        self.keep = keep
        self.pending: deque[Control] = deque()
        self.last_step: int | None = None
        self.received = 0
        self._event = trio.Event()
        self._scopes: set[trio.CancelScope] = set()
        self._token = trio.lowlevel.current_trio_token()
        self._sub = session.declare_subscriber(self.key, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        # A Zenoh thread (or the putting thread, same session): no actor state here.
        try:
            self._token.run_sync_soon(self._deliver, str(sample.key_expr),
                                      sample.payload.to_bytes())
        except trio.RunFinishedError:
            pass                                    # the actor's trio run is over
        except Exception:                           # pragma: no cover - never into Zenoh
            log.exception("control callback failed on %s", self.key)

    def _deliver(self, key_expr: str, payload: bytes) -> None:
        self.received += 1
        msg = self.counter.decode(key_expr, payload)
        if not isinstance(msg, Control):
            return
        if msg.command == "quit" and "last_step" in msg.args:
            last = msg.args["last_step"]
            if type(last) is not int:
                self.counter.reject(key_expr, f"quit: last_step must be an integer, got "
                                              f"{last!r}")
                return
            self.last_step = last if self.last_step is None else min(self.last_step, last)
            for scope in list(self._scopes):
                scope.cancel()
        if self.keep:
            self.pending.append(msg)
        self._event.set()
        self._event = trio.Event()

    def take(self) -> list[Control]:
        """The commands received since the last call, oldest first."""
        out = list(self.pending)
        self.pending.clear()
        return out

    async def wait(self) -> None:
        """Return when a command is pending (at once if one already is)."""
        if not self.pending:
            await self._event.wait()

    def ended(self, step: int) -> bool:
        """True when ``step`` lies after the run's announced last step."""
        return self.last_step is not None and step > self.last_step

    def interruptible(self, deadline: float = math.inf) -> Interruptible:
        """A cancel scope that the end marker cancels (wrap a wait for the next step), with
        an optional trio ``deadline``: one scope serves both."""
        return Interruptible(self._scopes, deadline)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # pragma: no cover - session already closed
            pass

    def __enter__(self) -> Controls:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Interruptible:
    """:meth:`Controls.interruptible`: a :class:`trio.CancelScope` registered with the
    controls while it is entered (a plain class: a ``contextmanager`` generator around it cost
    as much again on every wait of the step chain)."""

    __slots__ = ("scope", "scopes")

    def __init__(self, scopes: set[trio.CancelScope], deadline: float) -> None:
        self.scopes = scopes
        self.scope = trio.CancelScope(deadline=deadline)

    def __enter__(self) -> trio.CancelScope:
        scope = self.scope.__enter__()
        self.scopes.add(scope)
        return scope

    def __exit__(self, *exc: Any) -> bool:
        self.scopes.discard(self.scope)
        return self.scope.__exit__(*exc)


MIN_SPEED, MAX_SPEED = 0.01, 1e6
"""The range a positive ``speed`` is clamped to (steps/s)."""


@dataclass
class RunControl:
    """The clock commands — ``pause``, ``resume``, ``step``, ``speed``, ``quit`` — with the
    semantics of ``tui/driver.py``. The world obeys this state; the executor applies the same
    control stream to its own copy, so its status reports the world's pause and speed without
    asking it.

    ``default_speed`` is what ``speed 0`` means: 0 (as fast as possible) in lockstep, the
    configured tick rate under the realtime clock (where "as fast as possible" has no
    meaning: the world would never wait for a motor command).
    """

    paused: bool = False
    budget: int = 0
    """Steps still to take while paused (``step {"n": k}``)."""
    speed: float = 0.0
    """Steps/s: lockstep pace (0 = free) or realtime tick rate."""
    default_speed: float = 0.0
    quit: bool = False
    message: str = ""
    """The answer to the last command (``AgentStatus.message``)."""

    def apply(self, c: Control) -> bool:
        """Apply a clock command; False for the others (goal, save). Raises
        :class:`ControlError` for malformed arguments (the state is left as it was)."""
        a = c.args
        if c.command == "pause":
            self.paused, self.budget, self.message = True, 0, "paused"
        elif c.command == "resume":
            self.paused, self.budget, self.message = False, 0, "resumed"
        elif c.command == "step":
            n = max(1, _number(a, "n", 1, int))
            self.paused = True
            self.budget += n
            self.message = f"step {self.budget}"
        elif c.command == "speed":
            x = max(0.0, _number(a, "steps_per_s", 0.0, float))
            self.speed = min(max(x, MIN_SPEED), MAX_SPEED) if x > 0 else self.default_speed
            self.message = f"speed {self.speed:g} steps/s" if self.speed else "speed: free"
        elif c.command == "quit":
            self.quit = True
            last = a.get("last_step")
            self.message = "quit" if last is None else f"run ended after step {last}"
        else:
            return False
        return True

    @property
    def may_step(self) -> bool:
        """Whether the world may take its next step now."""
        return not self.quit and (not self.paused or self.budget > 0)

    def stepped(self) -> None:
        """One step was taken (uses up the single-step budget while paused)."""
        if self.budget > 0:
            self.budget -= 1


def _number(args: dict[str, Any], name: str, default: Any, kind: type) -> Any:
    """``args[name]`` as ``kind`` (int or float); bool, strings, lists... are malformed."""
    v = args.get(name, default)
    if type(v) not in (int, float) or (kind is int and v != int(v)):
        raise ControlError(f"{name} must be a{'n integer' if kind is int else ' number'}, "
                           f"got {v!r}")
    return kind(v)
