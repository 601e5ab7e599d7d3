"""A learner's batches as the actors run them (Algorithm 2 lines 6–13; docs/runtime.md,
Lockstep).

A batch at step t is computed on a copy of the learner — in the actor's task in lockstep
(the chain waits for its delta at t + L anyway; docs/decisions.md 92, 110), in a worker thread
under the realtime clock, so that no tick waits for it — and its parts are
published as deltas that every consumer applies at the boundary of t + L. A
:class:`DeltaOutbox` publishes one kind of delta, keeps it in the actor's replay log until
every consumer has applied it (a restarted consumer fetches what it missed) and shows the
batches in flight on the watchdog's board; :class:`Batches` starts the computations and
:func:`context_before` gets the executor's state a batch reads (§6.2.1).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import trio

from ..bus.schema import BatchContext, DeltaMsg
from ..qlap.delta import Delta
from ..qlap.learner import ModelLearner
from .actor import Actor, to_thread
from .batch_process import BatchProcess, BatchProcessError, peak_mib
from .context import RunContext
from .inbox import DeltaInbox, RunEnded, StepInbox
from .rules import batchctx_rule

log = logging.getLogger("qlap.batches")

class DeltaOutbox:
    """One actor's ``delta/<kind>`` topic: published, logged, and tracked while in flight."""

    def __init__(self, actor: Actor, kind: str) -> None:
        self.actor, self.kind = actor, kind
        self.output = actor.output(f"delta/{kind}")
        self.lag = actor.ctx.params.batch_lag
        self.in_flight: set[int] = set()
        """Steps of the batches computed but not yet published."""
        self.snapshot_pending = False
        for d in actor.resume.state.get("own", []):    # published before the snapshot
            self.log(DeltaMsg(kind, d))

    def log(self, msg: DeltaMsg) -> None:
        self.output.log.append(msg.to_delta().computed_at + self.lag, msg)

    def requeue(self, deltas: DeltaInbox) -> None:
        """Its own deltas logged but not yet applied (a restarted actor) go to ``deltas``."""
        for _, msg in self.output.log.entries():
            deltas.add(msg, live=False)

    def reserve(self, t: int) -> None:
        """A batch of this kind is in flight from ``t`` (on the board)."""
        self.in_flight.add(t)
        self.actor.slot.busy(len(self.in_flight))

    def publish(self, delta: Delta) -> None:
        msg = DeltaMsg.of(self.kind, delta)
        pub = self.output.pub
        if pub.put(msg) or pub.faults is None or not pub.faults.lost:
            self.output.log.append(delta.computed_at + self.lag, msg, pub.payload)
        self.in_flight.discard(delta.computed_at)
        self.actor.slot.busy(len(self.in_flight))

    def pending(self, step: int) -> list[DeltaMsg]:
        """Own deltas published but applied after ``step``."""
        return [m for _, m in self.output.log.entries(step + 1)]

    def snapshot_now(self, t: int) -> bool:
        """Whether the actor writes its snapshot at ``t``: when one is due, or was due while a
        batch was in flight (a snapshot must not miss a batch computed at or before it), and
        none is in flight now."""
        actor = self.actor
        self.snapshot_pending = self.snapshot_pending or actor.snapshot_due(t)
        if self.snapshot_pending and not self.in_flight and t + 1 < actor.ctx.end:
            self.snapshot_pending = False
            return True
        return False

    def snapshot(self, t: int, save: Callable[[Path], Any], consumers: tuple[str, ...]) -> None:
        """The actor's snapshot at ``t`` if :meth:`snapshot_now` (``save(dir)`` writes the
        algorithm's files). It keeps the own deltas a consumer restarted from its oldest
        snapshot may still need (the restarted actor serves them again)."""
        if self.snapshot_now(t):
            self.write_snapshot(t, save, consumers)

    def write_snapshot(self, t: int, save: Callable[[Path], Any] | None,
                       consumers: tuple[str, ...]) -> None:
        """The actor's snapshot at ``t`` now (:meth:`snapshot` without the schedule; a guest
        on its host's learner writes no algorithm files, ``save`` None)."""
        since = min(t, self.actor.oldest_snapshot(consumers))
        self.actor.snapshot(t, save, own=[m.delta for m in self.pending(since)])


class Batches:
    """One learning actor's batches: the executor's state each one reads (``batchctx``),
    its :class:`DeltaOutbox`, and the computing times."""

    def __init__(self, actor: Actor, kind: str, n_vars: int) -> None:
        ctx = self.ctx = actor.ctx
        # The executor's state before each batch (§6.2.1); the one before the first batch
        # after a snapshot may be of the snapshot's own step.
        self.contexts = actor.input("batchctx", window=ctx.replay_keep,
                                    rule=batchctx_rule(n_vars), first=actor.resume.step)
        self.out = DeltaOutbox(actor, kind)
        self.times: list[float] = []
        self.process: BatchProcess | None = None
        """The worker process the batches go to (docs/decisions.md 80; None: :attr:`inline`
        says where)."""
        self.away = 0
        """Batches computed in :attr:`process`."""
        self.away_mib: float | None = None

    @property
    def inline(self) -> bool:
        """The batch is computed in the actor's task, before its step ends, whenever the clock
        is lockstep and no worker process (:attr:`process`) takes it: with L = 0 (Algorithm
        2), in a process of its own (docs/decisions.md 92) and beside the step chain too
        (decision 110). A worker thread only shares the process's GIL — with the steps after
        t, which nothing waits for, or with the step chain, which then pays the batch, the
        switching and the cache it loses, and waits for the batch's delta at t + L all the
        same. Under the realtime clock a tick must not wait for a batch: worker threads."""
        return not self.ctx.realtime and self.process is None

    async def context(self, t: int) -> BatchContext | None:
        """The executor's state the batch at ``t`` reads (:func:`context_before`)."""
        return await context_before(self.contexts, t, self.ctx)

    async def begin(self, t: int, learner: ModelLearner | None, nursery: trio.Nursery,
                    prepare: Callable[[ModelLearner, BatchContext], None],
                    guest: Batches | None = None, work: ModelLearner | None = None) -> None:
        """The batch at ``t``: the executor's state it reads (``prepare(learner, context)``
        gives it to ``learner``), then :meth:`start`. ``guest``: the batches of the landmarks
        actor hosted on the same learner (docs/decisions.md 54), which take their part of the
        same computation and their own copy of the same context. ``work``: the batch copy
        already made (the executor's, :data:`HANDED`, docs/decisions.md 72; ``learner`` None),
        given the same context: copying and then setting the context gives what setting it
        and then copying gave (it sets ``reliable_actions`` and ``is_plan`` flags only)."""
        context = await self.context(t)
        if guest is not None:
            await guest.context(t)
        if context is not None:
            prepare(learner if work is None else work, context)
        outs = [self.out] if guest is None else [self.out, guest.out]
        await self.start(learner, t, outs, nursery, work)

    async def start(self, learner: ModelLearner | None, t: int, outs: list[DeltaOutbox],
                    nursery: trio.Nursery, work: ModelLearner | None = None) -> None:
        """The batch at ``t`` on a copy of ``learner`` (or on ``work``, a copy already):
        lines 6–9, then 10–13 when one of ``outs`` publishes landmarks; each of ``outs``
        publishes its part, in their order (dbn first: the order every consumer applies them
        in). When the batch runs in a worker thread the copy is made there too, while the
        actor awaits it (nothing else touches its learner), so that the trio loop goes on
        meanwhile: core's copy at step 2,000 held the loop 14 ms, a missed tick under the
        realtime clock."""
        landmarks = any(out.kind == "landmarks" for out in outs)
        kinds = ("dbn", "landmarks") if landmarks else ("dbn",)
        if work is None:
            assert learner is not None
            work = copy_for_batch(learner) if self.inline \
                else await to_thread(copy_for_batch, learner)
        for out in outs:
            out.reserve(t)
        if self.inline:
            self.publish(outs, self.compute(work, t, kinds))
        else:
            nursery.start_soon(self.background, work, t, kinds, outs)

    def compute(self, work: ModelLearner, t: int, kinds: tuple[str, ...]) -> dict[str, Delta]:
        t0 = time.perf_counter()
        parts = work.compute_parts(t, kinds)
        self.times.append(time.perf_counter() - t0)
        return parts

    @staticmethod
    def publish(outs: list[DeltaOutbox], parts: dict[str, Delta]) -> None:
        for out in outs:
            out.publish(parts[out.kind])

    def compute_away(self, work: ModelLearner, t: int, kinds: tuple[str, ...]
                     ) -> dict[str, Delta]:
        """:meth:`compute` in :attr:`process` (in this thread if it failed: the copy is
        unchanged, the answer the same)."""
        assert self.process is not None
        t0 = time.perf_counter()
        try:
            parts = self.process.compute(work, t, kinds)
        except BatchProcessError as exc:
            log.warning("%s; batches go on in threads", exc)
            self.process.close()
            self.process = None
            return self.compute(work, t, kinds)
        self.times.append(time.perf_counter() - t0)
        self.away += 1
        return parts

    async def background(self, work: ModelLearner, t: int, kinds: tuple[str, ...],
                         outs: list[DeltaOutbox]) -> None:
        fn = self.compute if self.process is None else self.compute_away
        self.publish(outs, await to_thread(fn, work, t, kinds))

    def result(self) -> dict[str, Any]:
        if self.process is not None:           # alive (a batch may still be in flight)
            self.away_mib = peak_mib(self.process.proc.pid)
        away = {"batches_in_process": self.away, "batch_process_peak_mib": self.away_mib}
        return {"batches": len(self.times), "batch_s": round(sum(self.times), 3),
                **(away if self.away else {})}


def hands_over(ctx: RunContext) -> bool:
    """Whether the executor hands the learning actors their batch copies (docs/decisions.md
    72): when they share the executor's process (``RunContext.together``: the embedded
    placement), in lockstep with a lag (with L = 0 the executor waits for
    the batch of t before it observes t; under the realtime clock the copy, made on the step
    chain, would hold the clock's task: decision 61 moved the learners' copies into their
    worker threads), and without snapshots (an actor without a learner has none to write)."""
    return ctx.together("executor", "contingency", "landmarks") and ctx.snapshots is None \
        and ctx.params.batch_lag > 0 and not ctx.realtime


class _Ended:
    """:meth:`HandedCopies.take`'s answer for a step after the run's last one."""


ENDED = _Ended()


class HandedCopies:
    """Batch copies of the executor's learner handed to the learning actors of the same
    process (docs/decisions.md 72), by run and step. The executor's follower keeps the pair
    statistics then, and at a batch step t, after observing ``qstate(t)`` and before the
    deltas due at t, it is the state a learning actor's own replica would be in (the state
    the planner's in-process request copies too); the learners then keep no replica that
    observes every step a second time. Used on one trio loop; a take waits for its put."""

    def __init__(self) -> None:
        self.copies: dict[tuple[str, int], ModelLearner | None] = {}
        self.waiting: dict[tuple[str, int], trio.Event] = {}
        self.last: dict[str, int] = {}
        """A run's last step, once its executor is done."""

    def put(self, run_id: str, step: int, learner: ModelLearner | None
            ) -> ModelLearner | None:
        """Hand over a batch copy of ``learner`` (made now: the learner goes on) and return
        it; None: step ``step`` was rejected, no batch starts there."""
        work = self.copies[(run_id, step)] = None if learner is None \
            else copy_for_batch(learner)
        self._wake(lambda key: key == (run_id, step))
        return work

    def end(self, run_id: str, last: int) -> None:
        """The run's executor took no step after ``last``."""
        self.last[run_id] = last
        self._wake(lambda key: key[0] == run_id)

    def _wake(self, which: Callable[[tuple[str, int]], bool]) -> None:
        for key in [k for k in self.waiting if which(k)]:
            self.waiting.pop(key).set()

    async def take(self, run_id: str, step: int) -> ModelLearner | _Ended | None:
        """The copy of ``step`` (waited for until the executor has observed that step), None
        for a rejected step, :data:`ENDED` after the run's last step (for a step after the
        run's end: waits until the executor is done)."""
        key = (run_id, step)
        while key not in self.copies:
            if step > self.last.get(run_id, step):
                return ENDED
            await self.waiting.setdefault(key, trio.Event()).wait()
        return self.copies.pop(key)

    def discard(self, run_id: str) -> None:
        """Forget a run (its learners are done): the copies nobody took, its end."""
        for key in [k for k in self.copies if k[0] == run_id]:
            del self.copies[key]
        self.last.pop(run_id, None)


HANDED = HandedCopies()


def copy_for_batch(learner: ModelLearner) -> ModelLearner:
    """A copy of ``learner`` that a batch may compute on while the learner goes on (with
    history rings of its own, :meth:`~qlap_runtime.qlap.learner.ModelLearner.batch_copy`,
    docs/decisions.md 63)."""
    return learner.batch_copy()


async def context_before(contexts: StepInbox, t: int, ctx: RunContext) -> BatchContext | None:
    """The executor's state after step t − 1 for the batch at t: waited for in lockstep (it is
    published before ``motor(t − 1)``, so it is on its way); under the realtime clock the
    latest that has arrived (None: none yet)."""
    if ctx.realtime:
        return contexts.latest()
    if t - 1 < ctx.start - 1:
        return None                       # never: a batch step is positive, and a resumed
                                          # run's executor publishes batchctx(start - 1)
    contexts.drop_before(t - 1)           # batches of the other actor's kind only
    try:
        return await contexts.get(t - 1, at=t)
    except RunEnded:
        return None
