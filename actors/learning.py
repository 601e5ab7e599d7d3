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

import trio

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.replay import ReplayLog, fetch_replay
from qlap_runtime.bus.schema import BatchContext, DeltaMsg
from qlap_runtime.qlap.checkpoint import load_learner, save_learner
from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.watchdog import Slot, slot_of

from .checkpoint_parts import final_dir, part_dir, save_statistics_part
from .common import (
    Controls,
    DeltaInbox,
    Resume,
    RunContext,
    RunEnded,
    StepInbox,
    apply_batch_context,
    oldest_consumer_snapshot,
    percept_from_qstate,
    resume_inputs,
    snapshot_due,
    snapshot_stats,
    world_variables,
    write_snapshot,
)
from .rules import batchctx_rule, qstate_rule

ROLES = {"contingency": "dbn", "landmarks": "landmarks"}
CONSUMERS = ("perception", "contingency", "landmarks", "executor")
"""Every actor that applies deltas."""


async def run(session, ctx: RunContext, role: str) -> dict:
    if role not in ROLES:
        raise ValueError(f"unknown learning role {role!r}; expected {sorted(ROLES)}")
    kind = ROLES[role]
    specs, _ = world_variables(ctx.world)
    resume = Resume.of(ctx, role)
    learner = load_learner(resume.path) if resume.path is not None \
        else ModelLearner(specs, ctx.params)
    learner.auto_batches = False
    counter = RejectionCounter(role)
    batch_s: list[float] = []
    snapshot_s: list[float] = []
    in_flight: set[int] = set()
    """Batch steps being computed in a worker thread (their delta not yet published)."""
    with declare_alive(session, ctx.run_id, role), \
            TrioSubscriber(session, keys.key(ctx.run_id, "qstate"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, f"delta/{kind}") as pub, \
            ReplayLog(session, ctx.run_id, f"delta/{kind}", ctx.replay_keep) as replay, \
            Controls(session, ctx, counter, keep=False) as end, \
            TrioSubscriber(session, keys.key(ctx.run_id, "batchctx"), counter=counter) as bsub:
        slot = slot_of(ctx, role)
        deltas = DeltaInbox(session, ctx, counter, slot, n_vars=len(learner.table))
        names = [v.name for v in learner.table]
        out = Outbox(pub, replay, kind, ctx.params.batch_lag, in_flight, slot)
        try:
            window = None if ctx.realtime else ctx.replay_keep
            inbox = StepInbox(sub, first=resume.step + 1, end=end, slot=slot, topic="qstate",
                              counter=counter, key=keys.key(ctx.run_id, "qstate"),
                              window=window, rule=qstate_rule(names))
            for d in resume.state.get("own", []):      # published before the snapshot
                out.log(DeltaMsg(kind, d))
            await resume_inputs(session, ctx, resume, inbox, "qstate", deltas, counter)
            # The executor's state before each batch (§6.2.1); the one before the first batch
            # after a snapshot may be of the snapshot's own step.
            contexts = StepInbox(bsub, first=resume.step, end=end, slot=slot,
                                 topic="batchctx", counter=counter,
                                 key=keys.key(ctx.run_id, "batchctx"), window=window,
                                 rule=batchctx_rule(len(learner.table)))
            if resume.restarted:
                await contexts.fill_from_replay(lambda step: fetch_replay(
                    session, ctx.run_id, "batchctx", step, counter=counter))
            for entry in replay.entries():
                deltas.add(entry[1], live=False)    # its own deltas not yet applied here
            snapshot_pending = False
            async with trio.open_nursery() as nursery:
                for t in range(resume.step + 1, ctx.start + ctx.steps):
                    try:
                        msg = await inbox.get(t)
                    except RunEnded:                # quit: the world took no step t
                        break
                    if msg.rejected:
                        deltas.book.skipped.add(t)
                    else:
                        learner.observe_percept(percept_from_qstate(msg, learner.table))
                        if kind in batch_kinds(ctx.params, t):
                            bc = await _context_before(contexts, t, ctx.start, ctx.realtime)
                            if bc is not None:
                                apply_batch_context(learner, bc)
                            work = learner.batch_copy()
                            in_flight.add(t)
                            slot.busy(len(in_flight))
                            if ctx.params.batch_lag == 0 and not ctx.realtime:
                                out.publish(_compute(work, t, kind, batch_s))
                            else:
                                nursery.start_soon(_background, work, t, kind, out, batch_s)
                        for d in await deltas.due_now(t, ctx.realtime):
                            learner.apply_delta(d)
                    slot.done(t)
                    if role == "contingency":       # the executor's checkpoint's part
                        save_statistics_part(part_dir(ctx, t), learner)
                    # A snapshot at t must not miss a batch computed at or before t: with one
                    # in flight it waits for the first step after its delta was published.
                    snapshot_pending = snapshot_pending or snapshot_due(ctx, t)
                    if snapshot_pending and not in_flight and t + 1 < ctx.start + ctx.steps:
                        snapshot_pending = False
                        # Its deltas a consumer restarted from its oldest snapshot may need.
                        since = min(t, oldest_consumer_snapshot(ctx, CONSUMERS))
                        snapshot_s.append(write_snapshot(
                            ctx, role, t, deltas, lambda d: save_learner(learner, d),
                            own=[m.delta for m in out.pending(since)]))
            slot.finished()
            if role == "contingency":
                save_statistics_part(final_dir(ctx), learner)
        finally:
            deltas.close()
    return {"rejected": counter.snapshot().total, "waits": deltas.book.waits,
            "batches": len(batch_s), "batch_s": round(sum(batch_s), 3),
            **snapshot_stats(snapshot_s, resume)}


async def _context_before(contexts: StepInbox, t: int, start: int,
                          realtime: bool) -> BatchContext | None:
    """The executor's state after step t − 1 for the batch at t: waited for in lockstep (it
    is published before ``motor(t − 1)``, so it is on its way); in realtime the latest that
    has arrived (None: none yet)."""
    if not realtime:
        if t - 1 < start:
            return None                       # before the run's first step: none published
        for old in [k for k in contexts.buf if k < t - 1]:
            contexts.drop(old)                 # batches of the other actor's kind only
        try:
            return await contexts.get(t - 1, at=t)
        except RunEnded:
            return None
    for r in contexts.sub.receive_nowait():
        contexts.add(r.msg, len(r.payload))
    if not contexts.buf:
        return None
    latest = max(contexts.buf)
    msg = contexts.buf[latest]
    contexts.buf.clear()
    contexts.buf[latest] = msg            # kept: the next batch may have no newer one
    return msg


class Outbox:
    """Publishes this learner's deltas and keeps them in its replay log until every consumer
    has applied them (a restarted consumer fetches those it missed)."""

    def __init__(self, pub: Publisher, replay: ReplayLog, kind: str, lag: int,
                 in_flight: set[int], slot: Slot | None = None) -> None:
        self.pub, self.replay, self.kind, self.lag = pub, replay, kind, lag
        self.in_flight = in_flight
        self.slot = slot if slot is not None else Slot()

    def log(self, msg: DeltaMsg) -> None:
        self.replay.append(msg.to_delta().computed_at + self.lag, msg)

    def publish(self, delta) -> None:
        msg = DeltaMsg.of(self.kind, delta)
        self.log(msg)
        self.pub.put(msg)
        self.in_flight.discard(delta.computed_at)
        self.slot.busy(len(self.in_flight))

    def pending(self, step: int) -> list[DeltaMsg]:
        """Own deltas published but applied after ``step`` (a snapshot at ``step`` keeps
        them: the restarted learner needs them and serves them again)."""
        return [m for s, m in self.replay.entries(step + 1)]


def _compute(work: ModelLearner, t: int, kind: str, times: list[float]):
    import time

    t0 = time.perf_counter()
    parts = work.compute_parts(t, ("dbn", "landmarks") if kind == "landmarks" else ("dbn",))
    times.append(time.perf_counter() - t0)
    return parts[kind]


async def _background(work: ModelLearner, t: int, kind: str, out: Outbox,
                      times: list[float]) -> None:
    delta = await trio.to_thread.run_sync(_compute, work, t, kind, times)
    out.publish(delta)
