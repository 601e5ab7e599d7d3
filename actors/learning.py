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
from qlap_runtime.bus.schema import DeltaMsg
from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.runtime.lockstep import batch_kinds

from .common import DeltaInbox, RunContext, StepInbox, percept_from_qstate, world_variables

ROLES = {"contingency": "dbn", "landmarks": "landmarks"}


async def run(session, ctx: RunContext, role: str) -> dict:
    if role not in ROLES:
        raise ValueError(f"unknown learning role {role!r}; expected {sorted(ROLES)}")
    kind = ROLES[role]
    specs, _ = world_variables(ctx.world)
    learner = ModelLearner(specs, ctx.params)
    learner.auto_batches = False
    counter = RejectionCounter(role)
    batch_s: list[float] = []
    with declare_alive(session, ctx.run_id, role), \
            TrioSubscriber(session, keys.key(ctx.run_id, "qstate"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, f"delta/{kind}") as pub:
        deltas = DeltaInbox(session, ctx, counter)
        try:
            async with trio.open_nursery() as nursery:
                inbox = StepInbox(sub)
                start = ctx.extra.get("start_step", 0)
                for t in range(start, start + ctx.steps):
                    msg = await inbox.get(t)
                    if msg.rejected:
                        deltas.book.skipped.add(t)
                        continue
                    learner.observe_percept(percept_from_qstate(msg, learner.table))
                    kinds = batch_kinds(ctx.params, t)
                    if kind in kinds:
                        work = learner.batch_copy()
                        if ctx.params.batch_lag == 0 and not ctx.realtime:
                            _publish(pub, kind, _compute(work, t, kind, batch_s))
                        else:
                            nursery.start_soon(_background, work, t, kind, pub, batch_s)
                    for d in await deltas.due_now(t, ctx.realtime):
                        learner.apply_delta(d)
        finally:
            deltas.close()
    return {"rejected": counter.snapshot().total, "waits": deltas.book.waits,
            "batches": len(batch_s), "batch_s": round(sum(batch_s), 3)}


def _compute(work: ModelLearner, t: int, kind: str, times: list[float]):
    import time

    t0 = time.perf_counter()
    parts = work.compute_parts(t, ("dbn", "landmarks") if kind == "landmarks" else ("dbn",))
    times.append(time.perf_counter() - t0)
    return parts[kind]


async def _background(work: ModelLearner, t: int, kind: str, pub: Publisher,
                      times: list[float]) -> None:
    delta = await trio.to_thread.run_sync(_compute, work, t, kind, times)
    _publish(pub, kind, delta)


def _publish(pub: Publisher, kind: str, delta) -> None:
    pub.put(DeltaMsg.of(kind, delta))
