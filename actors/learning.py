"""The two batch-learning actors (Algorithm 2 lines 6–13), sharing one implementation.

Both keep a :class:`~qlap_runtime.qlap.learner.ModelLearner` updated from the ``qstate``
stream (pair statistics, DBN activations, histories) and apply every delta at its step
boundary, so their states are identical replicas of the synchronous loop's learner.

- ``contingency`` computes lines 6–9 at every DBN batch (new DBNs, contexts, deletions) and
  publishes ``delta/dbn``.
- ``landmarks`` computes, at every landmark batch, lines 6–9 on a private copy (so that it sees
  the DBNs exactly as the sequential Algorithm 2 does) and then lines 10–13 (landmarks on events
  and on DBNs), and publishes ``delta/landmarks``.

With a batch lag L > 0 the computation runs on a copy in a worker thread while the actor keeps
consuming steps; its delta is applied by everyone at t + L. In the embedded placement both
actors run in one task on one learner (:func:`run_pair`): the statistics are kept once.
"""

from __future__ import annotations

import time
from typing import Any

import trio

from qlap_runtime.bus.schema import BatchContext, DeltaMsg
from qlap_runtime.qlap.checkpoint import load_learner, save_learner
from qlap_runtime.qlap.delta import Delta
from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.runtime.actor import Actor, ActorBase, Output, to_thread
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.inbox import RunEnded, StepInbox
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.rules import batchctx_rule, qstate_rule
from qlap_runtime.runtime.watchdog import Slot

from .checkpoint_parts import final_dir, part_dir, save_statistics_part
from .convert import QStateCodec, apply_batch_context
from .resume import checkpoint_of

ROLES = {"contingency": "dbn", "landmarks": "landmarks"}
CONSUMERS = ("perception", "contingency", "landmarks", "executor")
"""Every actor that applies deltas."""


class LearnerActor(ActorBase):
    """One batch-learning actor (``role`` contingency or landmarks): its learner, inputs and
    outputs, and its loop's step in three phases — :meth:`observe` (Algorithm 2 lines 2–5),
    :meth:`batch` (lines 6–9 or 6–13 on a copy) and :meth:`settle` (the deltas due, the
    snapshot).

    ``shared``: in the embedded placement both learners keep the same statistics from the same
    stream, so the contingency actor's task hosts the landmarks actor's steps on ONE learner
    (:func:`run_pair`): the host observes and applies the deltas, the guest only takes its
    messages (its rules and books as standalone) and computes its own batches. Each state a
    batch copies is the standalone actors' state at that step, so the deltas are the same.
    """

    def __init__(self, session: Any, ctx: RunContext, role: str,
                 shared: ModelLearner | None = None) -> None:
        if role not in ROLES:
            raise ValueError(f"unknown learning role {role!r}; expected {sorted(ROLES)}")
        self.ctx, self.role, self.kind = ctx, role, ROLES[role]
        self.guest = shared is not None
        self.batch_s: list[float] = []
        self.result: dict[str, Any] | None = None
        self.actor = actor = Actor(session, ctx, role)
        resume = actor.resume
        if shared is not None:
            learner = shared
        else:
            learner = self.load(ctx, resume)
        self.learner = learner
        self.codec = codec = QStateCodec(learner.table)
        n = len(learner.table)
        actor.input("qstate", window=ctx.replay_keep, rule=qstate_rule(codec.names))
        # The executor's state before each batch (§6.2.1); the one before the first batch
        # after a snapshot may be of the snapshot's own step.
        self.contexts = actor.input("batchctx", window=ctx.replay_keep, rule=batchctx_rule(n),
                                    first=resume.step)
        self.deltas = actor.deltas(n)
        self.out = Outbox(actor.output(f"delta/{self.kind}"), self.kind, ctx.params.batch_lag,
                          actor.slot)
        for d in resume.state.get("own", []):      # published before the snapshot
            self.out.log(DeltaMsg(self.kind, d))
        self.snapshot_pending = False
        self._msg: Any = None

    @staticmethod
    def load(ctx: RunContext, resume: Any) -> ModelLearner:
        """The learner to start from: a snapshot, a resumed run's checkpoint, or fresh."""
        checkpoint = checkpoint_of(ctx, resume.path)
        if resume.path is not None:
            learner = load_learner(resume.path)
        elif checkpoint is not None:            # a resumed run: the learner with its stats
            learner = load_learner(checkpoint)
            learner.follower = False
            learner.pending_deltas.clear()      # none: refused before the run otherwise
        else:
            specs, _ = world_variables(ctx.world)
            learner = ModelLearner(specs, ctx.params)
        learner.auto_batches = False
        return learner

    async def start(self) -> None:
        await self.actor.start()
        for _, msg in self.out.output.log.entries():
            self.deltas.add(msg, live=False)     # its own deltas not yet applied here

    async def observe(self, t: int) -> bool:
        """Take ``qstate(t)`` and learn from it (not a guest: its host did); False when the
        run ended before step t."""
        msg = await self.actor.receive(t, lazy=not self.guest)
        self._msg = msg
        if msg is None:
            return False
        if msg.rejected:
            self.deltas.book.skipped.add(t)
        elif not self.guest:
            self.learner.observe_percept(self.codec.percept(msg))
        return True

    async def batch(self, t: int, nursery: trio.Nursery,
                    guest: LearnerActor | None = None) -> None:
        """This actor's batch at ``t``, if one starts there: on a copy of the learner, in a
        worker thread when L > 0 (the actor goes on), its delta applied by all at t + L.

        ``guest`` (the landmarks actor on this learner, at one of its batch steps): its batch
        is computed on the same copy, lines 10–13 right after this one's lines 6–9, as the
        standalone landmarks actor computes them on its own identical copy; each actor
        publishes its part."""
        ctx, kind = self.ctx, self.kind
        if self._msg.rejected or kind not in batch_kinds(ctx.params, t):
            return
        bc = await _context_before(self.contexts, t, ctx.start, ctx.realtime)
        if guest is not None:                   # its own copy of the same context
            await _context_before(guest.contexts, t, ctx.start, ctx.realtime)
        if bc is not None:
            apply_batch_context(self.learner, bc)
        work = self.out.started(t, self.learner)
        outs = [(kind, self.out)]
        if guest is not None:
            guest.out.reserve(t)
            outs.append((guest.kind, guest.out))
        kinds = tuple(k for k, _ in outs) if guest is not None else \
            (("dbn", "landmarks") if kind == "landmarks" else ("dbn",))
        if ctx.params.batch_lag == 0 and not ctx.realtime:
            _publish(outs, _compute(work, t, kinds, self.batch_s))
        else:
            nursery.start_soon(_background, work, t, kinds, outs, self.batch_s)

    async def settle(self, t: int) -> None:
        """The deltas due at ``t`` (applied, unless a guest: its host applies them), the
        checkpoint's statistics part and the snapshot."""
        actor, ctx, learner, out = self.actor, self.ctx, self.learner, self.out
        if not self._msg.rejected:
            for d in await self.deltas.due_now(t, ctx.realtime):
                if not self.guest:
                    learner.apply_delta(d)
        actor.slot.done(t)
        if self.role == "contingency":          # the executor's checkpoint's part
            save_statistics_part(part_dir(ctx, t), learner)
        # A snapshot at t must not miss a batch computed at or before t: with one in flight
        # it waits for the first step after its delta was published.
        self.snapshot_pending = self.snapshot_pending or actor.snapshot_due(t)
        if self.snapshot_pending and not out.in_flight and t + 1 < ctx.end:
            self.snapshot_pending = False
            # Its deltas a consumer restarted from its oldest snapshot may need.
            since = min(t, actor.oldest_snapshot(CONSUMERS))
            actor.snapshot(t, lambda d: save_learner(learner, d),
                           own=[m.delta for m in out.pending(since)])

    async def finish(self) -> dict[str, Any]:
        """After the last step: the final statistics part; stay until the consumers are done."""
        self.actor.slot.finished()
        if self.role == "contingency":
            save_statistics_part(final_dir(self.ctx), self.learner)
        await self.actor.linger(CONSUMERS)      # a consumer behind may ask for a lost delta
        self.result = self.actor.result(batches=len(self.batch_s),
                                        batch_s=round(sum(self.batch_s), 3))
        return self.result



async def run(session: Any, ctx: RunContext, role: str) -> dict[str, Any]:
    """One learning actor as a task of its own."""
    with LearnerActor(session, ctx, role) as me:
        await me.start()
        async with trio.open_nursery() as nursery:
            for t in me.actor.steps():
                if not await me.observe(t):
                    break
                await me.batch(t, nursery)
                await me.settle(t)
        return await me.finish()


async def run_pair(session: Any, ctx: RunContext) -> dict[str, dict[str, Any]]:
    """Both learning actors in one task on one learner (the embedded placement): the
    contingency actor observes each step once and applies each delta once, the landmarks
    actor computes its batches on the same state (docs/decisions.md 54)."""
    with LearnerActor(session, ctx, "contingency") as host, \
            LearnerActor(session, ctx, "landmarks", shared=host.learner) as guest:
        await host.start()
        await guest.start()
        async with trio.open_nursery() as nursery:
            for t in host.actor.steps():
                if not await host.observe(t) or not await guest.observe(t):
                    break
                # One copy and one computation for both at a landmark batch step.
                both = "landmarks" in batch_kinds(ctx.params, t)
                await host.batch(t, nursery, guest if both else None)
                await guest.settle(t)
                await host.settle(t)
            # Both end together: each one's replay log waits for the other's token to go.
            nursery.start_soon(guest.finish)
            nursery.start_soon(host.finish)
        return {me.role: me.result for me in (host, guest)}


async def _context_before(contexts: StepInbox, t: int, start: int,
                          realtime: bool) -> BatchContext | None:
    """The executor's state after step t − 1 for the batch at t: waited for in lockstep (it
    is published before ``motor(t − 1)``, so it is on its way); in realtime the latest that
    has arrived (None: none yet)."""
    if realtime:
        return contexts.latest()
    if t - 1 < start - 1:
        return None                       # never: a batch step is positive, and a resumed
                                          # run's executor publishes batchctx(start - 1)
    contexts.drop_before(t - 1)           # batches of the other actor's kind only
    try:
        return await contexts.get(t - 1, at=t)
    except RunEnded:
        return None


class Outbox:
    """Publishes this learner's deltas and keeps them in its replay log until every consumer
    has applied them (a restarted consumer fetches those it missed); tracks the batches in
    flight (their delta not yet published) on the watchdog's board."""

    def __init__(self, output: Output, kind: str, lag: int, slot: Slot) -> None:
        self.output, self.kind, self.lag, self.slot = output, kind, lag, slot
        self.in_flight: set[int] = set()

    def log(self, msg: DeltaMsg) -> None:
        self.output.log.append(msg.to_delta().computed_at + self.lag, msg)

    def started(self, t: int, learner: ModelLearner) -> ModelLearner:
        """A batch starts at ``t``: the copy of the learner it computes on."""
        work = learner.batch_copy()
        self.reserve(t)
        return work

    def reserve(self, t: int) -> None:
        """A batch of this actor's kind is in flight from ``t`` (on the board)."""
        self.in_flight.add(t)
        self.slot.busy(len(self.in_flight))

    def publish(self, delta: Delta) -> None:
        msg = DeltaMsg.of(self.kind, delta)
        pub = self.output.pub
        if pub.put(msg) or pub.faults is None or not pub.faults.lost:
            self.log(msg)
        self.in_flight.discard(delta.computed_at)
        self.slot.busy(len(self.in_flight))

    def pending(self, step: int) -> list[DeltaMsg]:
        """Own deltas published but applied after ``step`` (a snapshot at ``step`` keeps
        them: the restarted learner needs them and serves them again)."""
        return [m for s, m in self.output.log.entries(step + 1)]


def _compute(work: ModelLearner, t: int, kinds: tuple[str, ...],
             times: list[float]) -> dict[str, Delta]:
    t0 = time.perf_counter()
    parts = work.compute_parts(t, kinds)
    times.append(time.perf_counter() - t0)
    return parts


def _publish(outs: list[tuple[str, Outbox]], parts: dict[str, Delta]) -> None:
    """Each actor's part, dbn first (the order every consumer applies them in)."""
    for kind, out in outs:
        out.publish(parts[kind])


async def _background(work: ModelLearner, t: int, kinds: tuple[str, ...],
                      outs: list[tuple[str, Outbox]], times: list[float]) -> None:
    _publish(outs, await to_thread(_compute, work, t, kinds, times))
