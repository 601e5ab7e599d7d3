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
consuming steps; its delta is applied by everyone at t + L.
"""

from __future__ import annotations

import time
from typing import Any

import trio

from qlap_runtime.bus.schema import BatchContext, DeltaMsg
from qlap_runtime.qlap.checkpoint import load_learner, save_learner
from qlap_runtime.qlap.delta import Delta
from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.runtime.actor import Actor, Output, to_thread
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


async def run(session: Any, ctx: RunContext, role: str) -> dict[str, Any]:
    if role not in ROLES:
        raise ValueError(f"unknown learning role {role!r}; expected {sorted(ROLES)}")
    kind = ROLES[role]
    specs, _ = world_variables(ctx.world)
    batch_s: list[float] = []
    with Actor(session, ctx, role) as actor:
        resume = actor.resume
        checkpoint = checkpoint_of(ctx, resume.path)
        if resume.path is not None:
            learner = load_learner(resume.path)
        elif checkpoint is not None:            # a resumed run: the learner with its stats
            learner = load_learner(checkpoint)
            learner.follower = False
            learner.pending_deltas.clear()      # none: refused before the run otherwise
        else:
            learner = ModelLearner(specs, ctx.params)
        learner.auto_batches = False
        codec, n = QStateCodec(learner.table), len(learner.table)
        actor.input("qstate", window=ctx.replay_keep, rule=qstate_rule(codec.names))
        # The executor's state before each batch (§6.2.1); the one before the first batch
        # after a snapshot may be of the snapshot's own step.
        contexts = actor.input("batchctx", window=ctx.replay_keep, rule=batchctx_rule(n),
                               first=resume.step)
        deltas = actor.deltas(n)
        out = Outbox(actor.output(f"delta/{kind}"), kind, ctx.params.batch_lag, actor.slot)
        for d in resume.state.get("own", []):      # published before the snapshot
            out.log(DeltaMsg(kind, d))
        await actor.start()
        for _, msg in out.output.log.entries():
            deltas.add(msg, live=False)             # its own deltas not yet applied here
        snapshot_pending = False
        async with trio.open_nursery() as nursery:
            for t in actor.steps():
                msg = await actor.receive(t, lazy=True)
                if msg is None:
                    break
                if msg.rejected:
                    deltas.book.skipped.add(t)
                else:
                    learner.observe_percept(codec.percept(msg))
                    if kind in batch_kinds(ctx.params, t):
                        bc = await _context_before(contexts, t, ctx.start, ctx.realtime)
                        if bc is not None:
                            apply_batch_context(learner, bc)
                        work = out.started(t, learner)
                        if ctx.params.batch_lag == 0 and not ctx.realtime:
                            out.publish(_compute(work, t, kind, batch_s))
                        else:
                            nursery.start_soon(_background, work, t, kind, out, batch_s)
                    for d in await deltas.due_now(t, ctx.realtime):
                        learner.apply_delta(d)
                actor.slot.done(t)
                if role == "contingency":           # the executor's checkpoint's part
                    save_statistics_part(part_dir(ctx, t), learner)
                # A snapshot at t must not miss a batch computed at or before t: with one in
                # flight it waits for the first step after its delta was published.
                snapshot_pending = snapshot_pending or actor.snapshot_due(t)
                if snapshot_pending and not out.in_flight and t + 1 < ctx.end:
                    snapshot_pending = False
                    # Its deltas a consumer restarted from its oldest snapshot may need.
                    since = min(t, actor.oldest_snapshot(CONSUMERS))
                    actor.snapshot(t, lambda d: save_learner(learner, d),
                                   own=[m.delta for m in out.pending(since)])
        actor.slot.finished()
        if role == "contingency":
            save_statistics_part(final_dir(ctx), learner)
        await actor.linger(CONSUMERS)           # a consumer behind may ask for a lost delta
    return actor.result(batches=len(batch_s), batch_s=round(sum(batch_s), 3))


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
        self.in_flight.add(t)
        self.slot.busy(len(self.in_flight))
        return work

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


def _compute(work: ModelLearner, t: int, kind: str, times: list[float]) -> Delta:
    t0 = time.perf_counter()
    parts = work.compute_parts(t, ("dbn", "landmarks") if kind == "landmarks" else ("dbn",))
    times.append(time.perf_counter() - t0)
    return parts[kind]


async def _background(work: ModelLearner, t: int, kind: str, out: Outbox,
                      times: list[float]) -> None:
    out.publish(await to_thread(_compute, work, t, kind, times))
