"""Both learning actors in one task, when they share a process (docs/runtime.md, Placements):
on one learner (:func:`run_pair`), or, in the executor's process with a lag, on none — their
batches then compute on the copies of its learner the executor hands over (:func:`run_handed`,
docs/decisions.md 72).
"""

from __future__ import annotations

from contextlib import ExitStack
from typing import Any

import trio

from qlap_runtime.runtime.batch_process import BatchProcess, wanted
from qlap_runtime.runtime.batches import ENDED, HANDED, hands_over
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.lockstep import batch_kinds

from .convert import apply_batch_context
from .learning import LearnerActor


async def run_pair(session: Any, ctx: RunContext) -> dict[str, dict[str, Any]]:
    """Both learning actors in one task on one learner (when they share a process): the
    contingency actor observes each step and applies each delta once; one batch copy serves
    both; both snapshot at the same steps (:meth:`LearnerActor.settle`), so that a restarted
    pair resumes both, and the shared learner, from one step. In the executor's process with
    a lag they keep no learner (:func:`run_handed`)."""
    if hands_over(ctx):
        return await run_handed(session, ctx)
    with LearnerActor(session, ctx, "contingency") as host, \
            LearnerActor(session, ctx, "landmarks", shared=host.learner) as guest:
        await host.start()
        await guest.start()
        async with trio.open_nursery() as host.nursery:
            for t in host.actor.steps():
                if not await host.observe(t) or not await guest.observe(t):
                    break
                both = "landmarks" in batch_kinds(ctx.params, t)
                await host.batch(t, guest if both else None)
                await guest.settle(t)
                await host.settle(t, guest)
            # Both end together: each one's replay log waits for the other's token to go.
            host.nursery.start_soon(guest.finish)
            host.nursery.start_soon(host.finish)
        return {me.role: me.result for me in (host, guest)}


async def run_handed(session: Any, ctx: RunContext) -> dict[str, dict[str, Any]]:
    """Both learning actors in one task on no learner (embedded with a lag, docs/decisions.md
    72). The executor's learner keeps every statistic a batch reads and, at each batch step t,
    hands over its copy after observing ``qstate(t)`` and before the deltas due at t: the
    state this pair's own learner would have had (:data:`~qlap_runtime.runtime.batches.
    HANDED`). The pair then takes only those copies — no ``qstate``, no deltas, no per-step
    learning — and computes the batch on each, with ``batchctx(t − 1)`` as before; the
    executor writes the checkpoints' statistics part. With ``QLAP_BATCH_PROCESS=1`` the
    batches compute in a worker process (docs/decisions.md 80); otherwise in this task in
    lockstep (decision 110) and in threads under the realtime clock."""
    HANDED.discard(ctx.run_id)                  # an earlier run's, of the same id
    with LearnerActor(session, ctx, "contingency", handed=True) as host, \
            LearnerActor(session, ctx, "landmarks", handed=True) as guest, ExitStack() as stack:
        if wanted():
            host.batches.process = process = BatchProcess()
            stack.callback(process.close)
        await host.start()
        await guest.start()
        async with trio.open_nursery() as host.nursery:
            for t in host.actor.steps():
                kinds = batch_kinds(ctx.params, t)
                if not kinds:
                    continue
                work = await HANDED.take(ctx.run_id, t)
                if work is ENDED:               # the run ended before t (a quit)
                    break
                if work is not None:            # None: step t was rejected, no batch
                    await host.batches.begin(t, None, host.nursery, apply_batch_context,
                                             guest.batches if "landmarks" in kinds else None,
                                             work=work)
                host.actor.slot.done(t)
                guest.actor.slot.done(t)
            else:                               # alive until the executor's last step
                await HANDED.take(ctx.run_id, ctx.end)
            HANDED.discard(ctx.run_id)
            host.nursery.start_soon(guest.finish)
            host.nursery.start_soon(host.finish)
        return {me.role: me.result for me in (host, guest)}
