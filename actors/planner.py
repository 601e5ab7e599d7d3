"""The planner actor: plan compilation off the step chain (Algorithm 2 line 15; §5.2–5.4, §6.2).

At every batch step t the executor publishes ``planreq(t)``: its agent after observing
``qstate(t)``, before the deltas due at t (the state the batch at t copies). The planner applies
that batch's deltas (``delta/dbn``, ``delta/landmarks`` computed at t) to it, compiles — plans
removed, second-order contexts C_o learned, DBNs converted, MDPs rebuilt with value iteration
(:meth:`~qlap_runtime.qlap.agent.Agent.compile_plans`) — and publishes ``delta/plans``, which the
executor applies at t + L right after the batch's deltas (docs/runtime.md, docs/decisions.md
56). The synchronous loop computes the same on a copy, so the knowledge is the same.

The planner keeps no state between batches: a restarted one resumes after the last batch its
snapshot names and fetches the requests and deltas again from their writers' replay logs.
"""

from __future__ import annotations

import time
from typing import Any

from qlap_runtime.bus.schema import PlanDeltaMsg
from qlap_runtime.qlap.variables import VariableTable
from qlap_runtime.runtime.actor import Actor, ActorBase, to_thread
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.inbox import RunEnded
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.rules import planreq_rule

from .convert import REQUEST_FILES, BadRequest, compile_request

NAME = "planner"
MAX_BAD_REQUESTS = 3
"""Requests of one step that hold no agent before the planner gives up (a forgery is
replaced by the executor's own request; the same failure again is the executor's)."""


def compiled_steps(ctx: RunContext, after: int) -> list[int]:
    """The batch steps after ``after`` whose plan delta applies within the run (t + L <
    ``ctx.end``): those the executor asks the planner for."""
    lag = ctx.params.batch_lag
    return [t for t in range(after + 1, ctx.end - lag) if batch_kinds(ctx.params, t)]


def requested_steps(ctx: RunContext, after: int) -> list[int]:
    """The steps after ``after`` with a ``planreq``: the compiled ones, and the last step
    (the planner ends there; it stays alive until the end of the run, as every actor)."""
    steps = compiled_steps(ctx, after)
    last = ctx.end - 1
    return steps + ([last] if last > after and last not in steps else [])


class PlannerActor(ActorBase):
    """The planner: ``planreq(t)`` and the batch's deltas -> ``delta/plans`` (computed in a
    worker thread, so that the other actors go on, unless it shares the step chain's process
    in lockstep: :attr:`inline`)."""

    def __init__(self, session: Any, ctx: RunContext) -> None:
        self.ctx = ctx
        self.actor = actor = Actor(session, ctx, NAME)
        # Requests come at batch steps only; a restart resumes at one (see batch).
        self.requests = actor.input("planreq", window=ctx.replay_keep,
                                    rule=planreq_rule(REQUEST_FILES,
                                                      ctx.together(NAME, "executor")))
        self.deltas = actor.deltas(len(VariableTable.from_specs(world_variables(ctx.world)[0])))
        self.out = actor.output("delta/plans")
        actor.restore_log(self.out, actor.resume.state.get("own", []))
        self.compile_s: list[float] = []
        self.result: dict[str, Any] | None = None
        self.inline = ctx.together(NAME, "world") and not ctx.realtime
        """Compile in this task, holding the trio loop (docs/decisions.md 93): beside the step
        chain in lockstep a worker thread would share its GIL with the chain, which then pays
        the compilation and the switching (0.72 s of the thread's CPU in 30,000 core steps
        against 0.33 s inline in the synchronous loop) and gains nothing from the wait."""

    async def batch(self, t: int) -> bool:
        """Answer ``planreq(t)``; False when the run ended (before t, or at the last step).
        A request that holds no agent is counted and asked for again (:class:`BadRequest`)."""
        due: list | None = None
        bad = 0
        while True:
            try:
                req = await self.requests.get(t)
            except RunEnded:
                return False
            if req.last:
                return False
            if req.rejected:                        # no batch at t: nothing to compile
                self.deltas.book.skipped.add(t)
                return True
            if due is None:                         # handed out once
                due = await self.deltas.due(t + self.ctx.params.batch_lag)
            t0 = time.perf_counter()
            self.actor.slot.busy(1)
            args = (req, due, self.ctx.params.batch_lag, self.ctx.run_id)
            try:
                delta = compile_request(*args) if self.inline \
                    else await to_thread(compile_request, *args)
                break
            except BadRequest as e:
                self.actor.counter.reject(self.requests.key, str(e))
                bad += 1
                if bad >= MAX_BAD_REQUESTS:         # not a forgery: the executor's own
                    raise RuntimeError(f"{e} ({bad} times: the executor's request itself "
                                       "cannot be read)") from None
                self.requests.again(t)
            finally:
                self.actor.slot.busy(0)
        self.compile_s.append(time.perf_counter() - t0)
        self.out.put(t, PlanDeltaMsg.of(delta))
        self.actor.slot.done(t)
        return True

    def mark(self, t: int) -> None:
        """Before waiting for ``planreq(t)``: a snapshot named after step t − 1 (nothing
        happens between two requests), so that a restarted planner starts at t. It keeps the
        plan deltas that the executor, restarted from its oldest snapshot, may still need."""
        if self.ctx.snapshots is None or t - 1 <= self.actor.resume.step:
            return
        since = self.actor.oldest_snapshot(("executor",)) - self.ctx.params.batch_lag
        self.actor.snapshot(t - 1, None, own=self.out.saved(since + 1))

    async def finish(self) -> dict[str, Any]:
        """After the last batch: stay until the executor is done (it may ask again)."""
        self.actor.slot.finished()
        await self.actor.linger(("executor",))
        self.result = self.actor.result(compilations=len(self.compile_s),
                                        compile_s=round(sum(self.compile_s), 3))
        return self.result


async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    """The planner actor as a task of its own."""
    with PlannerActor(session, ctx) as me:
        await me.actor.start()
        for t in requested_steps(ctx, me.actor.resume.step):
            me.mark(t)
            if not await me.batch(t):
                break
        return await me.finish()
