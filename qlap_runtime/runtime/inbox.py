"""Step-indexed inboxes: what an actor receives, in lockstep order (docs/runtime.md).

:class:`StepInbox` hands out one topic's messages by step (``await get(t)``) and
:class:`DeltaInbox` the knowledge deltas due at a step boundary. Both apply the rules on
messages (:mod:`.rules`) before anything else, bound what may wait for later steps, drop what a
restarted writer publishes again, report every wait on the watchdog's board, and, in lockstep,
ask the writers' replay logs again for what does not come in time (a lost message, a restart).
"""

from __future__ import annotations

import math
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

import trio

from ..bus import keys
from ..bus.bridge import RejectionCounter, TrioSubscriber
from ..bus.replay import fetch_replay
from ..bus.schema import DeltaMsg
from .context import RunContext
from .lockstep import DeltaBook
from .rules import delta_rule
from .watchdog import Slot

if TYPE_CHECKING:
    from .controls import Controls


MAX_PENDING_BYTES = 64 * 2**20
"""Per inbox: the payload bytes of messages received for later steps that may wait there. A
run's own messages never come near it (a core2d ``qstate`` is ~0.5 kB and the window a few
thousand steps); a sender flooding valid far-future messages is rejected beyond it."""

REFILL_FIRST_S = 0.1
"""A lockstep consumer whose step has not arrived this long after it started waiting asks the
writer's replay log again (a message lost on the way, or put while a restarted consumer's
subscription was still propagating); the wait doubles after every fruitless ask, up to
:data:`REFILL_MAX_S`, so an idle run (paused) costs one small query every few seconds."""
REFILL_GAP_S = 0.05
"""The first ask comes this soon when a later step is already held: the step was lost."""
REFILL_MAX_S = 2.0


class Refills:
    """When a waiting inbox asks the replay logs again (:data:`REFILL_FIRST_S`): a deadline
    that starts short and doubles after every ask."""

    def __init__(self, gap: bool) -> None:
        self.wait = REFILL_GAP_S if gap else REFILL_FIRST_S
        self.deadline = trio.current_time() + self.wait
        self.asked = 0

    def gap(self) -> None:
        """A later step arrived while this one is missing: ask soon, unless already asked."""
        if not self.asked:
            self.deadline = min(self.deadline, trio.current_time() + REFILL_GAP_S)

    def due(self) -> bool:
        return trio.current_time() >= self.deadline

    def asked_now(self) -> None:
        self.asked += 1
        self.wait = min(2 * max(self.wait, REFILL_FIRST_S), REFILL_MAX_S)
        self.deadline = trio.current_time() + self.wait


class StepInbox:
    """Messages of one topic, indexed by step; ``await get(t)`` returns step t's message.

    Steps below the next one expected are dropped: a writer restarted from a snapshot publishes
    again the steps after its snapshot, which this consumer may already have consumed.
    ``refill(step)`` (a fetch from the writer's replay log) fills gaps: a step that does not
    come in time (:class:`Refills`) is asked for again.

    Rules (docs/runtime.md, "Rules on messages"): a live message more than ``window`` steps
    after the next step expected (or the last one fetched from a replay log) is outside the
    lockstep window; ``rule(msg)`` returns why a message cannot be one of the run's; the payload
    bytes waiting are bounded by ``MAX_PENDING_BYTES``. Such messages are counted and logged by
    ``counter`` on ``key`` and dropped.
    """

    def __init__(self, sub: TrioSubscriber, first: int = 0,
                 refill: Callable[[int], Awaitable[list]] | None = None,
                 end: Controls | None = None, slot: Slot | None = None,
                 topic: str = "", *, counter: RejectionCounter | None = None, key: str = "",
                 window: int | None = None,
                 rule: Callable[[Any], str | None] | None = None) -> None:
        self.sub = sub
        self.counter = counter if counter is not None else RejectionCounter()
        self.key = key or topic
        self.window = window
        self.rule = rule
        self.high = -1
        """The last step fetched from a replay log (a restarted actor's window starts there)."""
        self.sizes: dict[int, int] = {}
        self.pending_bytes = 0
        self.slot = slot if slot is not None else Slot()
        """Where a wait is reported for the watchdog (:mod:`~qlap_runtime.runtime.watchdog`)."""
        self.topic = topic
        self.buf: dict[int, Any] = {}
        self.next = first
        self.refill = refill
        self.end = end
        """The run's controls: :meth:`get` raises :class:`RunEnded` for a step after the last
        one the world announced (``quit``)."""
        self.seen = 0
        """The subscriber's messages counted when :meth:`discard` last looked."""
        self.duplicates = 0
        """Messages dropped because their step was already consumed."""
        self.refills = 0
        """Times the replay log was asked again for a step that did not come."""

    def add(self, msg: Any, size: int = 0, live: bool = True) -> bool:
        """Keep ``msg`` for its step (``size``: its payload bytes; ``live``: from the
        subscription, not a replay log); False if it was dropped."""
        step = msg.step
        if self.rule is not None:                   # first: a forgery is always counted
            why = self.rule(msg)
            if why is not None:
                return self._reject(why)
        if step < self.next:
            self.duplicates += 1
            return False
        if live:
            if self.window is not None and step > max(self.next, self.high) + self.window:
                return self._reject(f"step {step} outside the lockstep window (next "
                                    f"{self.next}, window {self.window})")
            if self.pending_bytes + size - self.sizes.get(step, 0) > MAX_PENDING_BYTES:
                return self._reject(f"step {step}: more than {MAX_PENDING_BYTES} bytes of "
                                    "messages for later steps pending")
        self.pending_bytes += size - self.sizes.get(step, 0)
        self.sizes[step] = size
        self.buf[step] = msg
        if not live:
            self.high = max(self.high, step)
        return True

    def _reject(self, reason: str) -> bool:
        self.counter.reject(self.key, reason)
        return False

    def drain(self) -> None:
        """Keep every message that has arrived, without waiting."""
        for r in self.sub.receive_nowait():
            self.add(r.msg, len(r.payload))

    def discard(self, step: int) -> None:
        """A hosted input (:meth:`~qlap_runtime.runtime.actor.Actor.input`): keep the rules on
        what has arrived (counted, as :meth:`get` would) and forget it up to ``step``, whose
        message the actor took in memory. Nothing to do, the common case, is one comparison:
        nothing arrived since the last call."""
        if self.sub.received != self.seen:
            self.seen = self.sub.received
            self.drain()
        if self.buf:
            self.drop_before(step + 1)
        if step >= self.next:
            self.next = step + 1

    def again(self, step: int) -> None:
        """Take step ``step``'s message again: the one :meth:`get` returned could not be used
        (a forgery that passed the rules); the next one for ``step``, or the writer's logged
        one (the refill), replaces it."""
        self.drop(step)
        self.next = min(self.next, step)

    def ready(self, step: int) -> bool:
        """Whether step ``step``'s message is here (what has arrived is kept first)."""
        if step not in self.buf:
            self.drain()
        return step in self.buf

    def latest(self) -> Any | None:
        """The newest message held, keeping only it (the realtime clock's batch context:
        the next batch may have no newer one); None when none is held."""
        self.drain()
        if not self.buf:
            return None
        newest = max(self.buf)
        for step in [s for s in self.buf if s != newest]:
            self.drop(step)
        return self.buf[newest]

    def drop_before(self, step: int) -> None:
        """Forget the messages of steps before ``step`` (never to be consumed)."""
        for old in [s for s in self.buf if s < step]:
            self.drop(old)

    def drop(self, step: int) -> None:
        """Forget the message of ``step`` (not to be consumed)."""
        self.buf.pop(step, None)
        self.pending_bytes -= self.sizes.pop(step, 0)

    async def get(self, step: int, at: int | None = None) -> Any:
        """Step ``step``'s message (waited for; the wait is on the board, before passing step
        ``at``, by default ``step``)."""
        if not self.ready(step):                # what has arrived first: no wait then
            self.slot.wait(self.topic, step, at)
            try:
                await self._wait_for(step)
            finally:
                self.slot.clear()
        self.next = max(self.next, step + 1)
        self.pending_bytes -= self.sizes.pop(step, 0)
        return self.buf.pop(step)

    async def _wait_for(self, step: int) -> None:
        refills = Refills(any(s > step for s in self.buf)) if self.refill is not None else None
        while step not in self.buf:
            end = self.end
            if end is not None and end.ended(step):
                raise RunEnded(end.last_step)       # type: ignore[arg-type]
            batch: list = []
            # One cancel scope per wait (they cost more than the rest of a step's wait): the
            # refill deadline, cancelled early by the end marker.
            deadline = math.inf if refills is None else refills.deadline
            with end.interruptible(deadline) if end is not None \
                    else trio.CancelScope(deadline=deadline):
                batch = await self.sub.receive_batch()
            for r in batch:
                self.add(r.msg, len(r.payload))
            if refills is None or step in self.buf or (end and end.ended(step)):
                continue
            if batch and any(s > step for s in self.buf):
                refills.gap()
            # Not here in time: ask the replay log again (a lost message, or a writer that was
            # itself restarting when a restarted actor first asked: chaos trials).
            if refills.due():
                assert self.refill is not None
                for msg in await self.refill(step):
                    self.add(msg, live=False)
                refills.asked_now()
                self.refills += 1

    async def fill_from_replay(self, refill: Callable[[int], Awaitable[list]]) -> int:
        """Add the writer's logged messages from :attr:`next` on (a restarted consumer, after
        subscribing); keep ``refill`` for gaps; return how many were added."""
        self.refill = refill
        msgs = await refill(self.next)
        for msg in msgs:
            self.add(msg, live=False)
        return len(msgs)


class RunEnded(Exception):
    """The world ended the run early (``quit``): there is no step after :attr:`last_step`."""

    def __init__(self, last_step: int) -> None:
        super().__init__(f"the run ended after step {last_step}")
        self.last_step = last_step


class DeltaInbox:
    """Receives ``delta/*`` and hands out those due at a step, in apply order.

    A delta whose turn has passed (already applied here) is ignored: a learner restarted from a
    snapshot recomputes and publishes again the batches after its snapshot.
    """

    def __init__(self, session: Any, ctx: RunContext, counter: RejectionCounter,
                 slot: Slot | None = None, n_vars: int | None = None) -> None:
        self.book = DeltaBook(ctx.params)
        self.book.last = ctx.start - 1             # a resumed run applied those before
        self.slot = slot if slot is not None else Slot()
        self.counter = counter
        self.keys = {k: keys.key(ctx.run_id, f"delta/{k}") for k in ("dbn", "landmarks")}
        self.rule = None if n_vars is None else delta_rule(ctx.params, n_vars, ctx.realtime)
        self.window = None if ctx.realtime else ctx.replay_keep
        self.start = ctx.start
        self.sizes: dict[tuple[int, str], int] = {}
        self.pending_bytes = 0
        self.sub = TrioSubscriber(session, f"{keys.ROOT}/{ctx.run_id}/delta/*", counter=counter)
        self.wait_s = 0.0
        self.realtime = ctx.realtime
        self.stale = 0
        self.refills = 0
        self.refill: Callable[[int], Awaitable[list]] | None = None
        """Fetches the learners' delta logs again, from a step boundary on, when a due delta
        does not come (lockstep; None under the realtime clock, where deltas apply when they
        arrive)."""
        if not ctx.realtime:
            self.refill = self._refill_from(session, ctx, counter)

    def add(self, msg: DeltaMsg, size: int = 0, live: bool = True) -> None:
        """Keep a delta until it is due (counted and dropped if it breaks a rule)."""
        if msg.kind not in ("dbn", "landmarks"):
            return
        if self.rule is not None:                   # first: a forgery is always counted
            why = self.rule(msg)
            if why is not None:
                self.counter.reject(self.keys[msg.kind], why)
                return
        at = msg.delta["computed_at"]
        lag = 0 if self.realtime else self.book.params.batch_lag
        done = at + lag                             # the step at whose boundary it applies
        if done <= self.book.last:
            self.stale += 1
            return
        key = (at, msg.kind)
        if live and self.window is not None \
                and at > max(self.book.last, self.start - 1) + self.window:
            self.counter.reject(self.keys[msg.kind],
                                f"delta/{msg.kind} computed at {at}: outside the "
                                f"lockstep window (last applied step "
                                f"{self.book.last}, window {self.window})")
            return
        if live and self.pending_bytes + size - self.sizes.get(key, 0) > MAX_PENDING_BYTES:
            self.counter.reject(self.keys[msg.kind],
                                f"delta/{msg.kind} computed at {at}: more than "
                                f"{MAX_PENDING_BYTES} bytes of deltas pending")
            return
        self.pending_bytes += size - self.sizes.get(key, 0)
        self.sizes[key] = size
        self.book.add(msg.kind, msg.to_delta())

    def _popped(self, deltas: list) -> list:
        for d in deltas:
            for kind in ("dbn", "landmarks"):
                self.pending_bytes -= self.sizes.pop((d.computed_at, kind), 0)
        return deltas

    def take(self, batch: list) -> None:
        """Keep a batch of received deltas (``TrioSubscriber`` records)."""
        for r in batch:
            self.add(r.msg, len(r.payload))

    def drain(self) -> None:
        """Keep every delta that has arrived, without waiting."""
        self.take(self.sub.receive_nowait())

    @staticmethod
    def _refill_from(session: Any, ctx: RunContext,
                     counter: RejectionCounter) -> Callable[[int], Awaitable[list]]:
        async def refill(boundary: int) -> list:
            # The learners log a delta under the boundary it applies at (computed_at + L).
            return await fetch_replay(session, ctx.run_id, "delta/*", boundary, counter=counter)
        return refill

    async def catch_up(self, session: Any, ctx: RunContext, counter: RejectionCounter) -> int:
        """A restarted actor: add every delta the learners' replay logs hold (after
        subscribing, so none published meanwhile is lost); return how many came back."""
        self.refill = refill = self.refill or self._refill_from(session, ctx, counter)
        msgs = await refill(0)
        for msg in msgs:
            self.add(msg, live=False)
        return len(msgs)

    async def due(self, step: int) -> list:
        if self.sub.pending():
            self.drain()
        if self.book.none_due(step):            # most steps: nothing to hand out
            self.book.last = step
            return []
        if not self.book.ready(step):
            self.book.waits += 1
            t0 = time.perf_counter()
            refills = Refills(False) if self.refill is not None else None
            while not self.book.ready(step):
                computed, kind = self.book.missing(step)[0]
                with self.slot.waiting(f"delta/{kind}", computed, step):
                    if refills is None:
                        self.take(await self.sub.receive_batch())
                        continue
                    # Not here in time: ask the learners' replay logs again (a lost delta, or
                    # a learner that was itself restarting when a restarted actor asked), for
                    # the deltas not applied yet only (those before are stale here): the
                    # chain decoded every delta of the run at every refill before.
                    batch: list = []
                    with trio.move_on_at(refills.deadline):
                        batch = await self.sub.receive_batch()
                    self.take(batch)
                    if not self.book.ready(step) and refills.due():
                        for msg in await self.refill(self.book.last + 1):  # type: ignore[misc]
                            self.add(msg, live=False)
                        refills.asked_now()
                        self.refills += 1
            self.wait_s += time.perf_counter() - t0
        return self._popped(self.book.pop_due(step))

    async def due_now(self, step: int, realtime: bool) -> list:
        """Lockstep: :meth:`due` (waits). Realtime: what has arrived, applied on arrival."""
        if not realtime:
            return await self.due(step)
        self.drain()
        return self._popped(self.book.arrived_prefix(step))

    def close(self) -> None:
        self.sub.close()


