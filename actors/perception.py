"""The perception actor: ``sense(t)`` -> ``qstate(t)`` with the current landmarks (ch. 3).

Standalone (:func:`run`) it is a task of its own; in the embedded placement the world's task
calls :meth:`PerceptionActor.step` right after publishing ``sense(t)``, which the session has
already handed to this actor's inbox (docs/decisions.md 52). Its skeleton — inputs, rules,
replay log, snapshots — is :mod:`qlap_runtime.runtime.actor`'s.
"""

from __future__ import annotations

from typing import Any

from qlap_runtime.bus import keys
from qlap_runtime.bus.schema import QState, Sense
from qlap_runtime.qlap.perception import InvalidObservation
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.snapshot import save_perception
from qlap_runtime.runtime.start_state import start_perception

from .convert import QStateCodec, apply_landmark_ops, rejection_as_sent

NAME = "perception"
CONSUMERS = ("contingency", "landmarks", "executor")


class PerceptionActor(ActorBase):
    """The perception actor: its quantity spaces, inputs and outputs, one step of its loop."""

    def __init__(self, session: Any, ctx: RunContext) -> None:
        self.ctx = ctx
        self.actor = actor = Actor(session, ctx, NAME)
        self.per = start_perception(ctx, actor.resume)
        self.codec = QStateCodec(self.per.table)
        self.rejected_obs = 0
        # On the step chain: sense(t + 1) exists only once qstate(t) went out (window 1;
        # unknown variables are rejected by perceive, as in the synchronous loop).
        actor.input("sense", window=1)
        self.deltas = actor.deltas(len(self.per.table))
        self.out = actor.output("qstate")
        actor.restore_log(self.out, actor.resume.state.get("qstate", []))
        self.last_observed = int(actor.resume.state.get("last_observed", ctx.start - 1))

    async def step(self, t: int) -> bool:
        """``sense(t)`` -> ``qstate(t)``; False when the run ended before step t."""
        actor, ctx = self.actor, self.ctx
        msg = await actor.receive(t)
        if msg is None:
            return False
        seen = self.last_observed
        if seen >= ctx.start and seen > self.deltas.book.last:
            # Deltas applied at the boundary of the last observed step change the landmarks
            # used from t on.
            apply_landmark_ops(self.per, await self.deltas.due_now(seen, ctx.realtime))
        self.out.put(t, self.perceive(t, msg))
        actor.slot.done(t)
        if actor.snapshot_due(t):
            # The qstate log after the oldest consumer snapshot goes with it: a consumer
            # restarted from that snapshot after this actor restarted fetches them from the
            # new process (chaos trials, issue 13).
            since = actor.oldest_snapshot(CONSUMERS) + 1
            actor.snapshot(t, lambda d: save_perception(self.per, d),
                           last_observed=self.last_observed, qstate=self.out.saved(since))
        return True

    def perceive(self, t: int, msg: Sense) -> QState:
        """The qualitative state of ``sense(t)``, or its rejection (every actor skips t)."""
        per = self.per
        try:
            p = per.perceive(t, per.vector(msg.values), copy=False,
                             discontinuity=msg.discontinuity)
        except InvalidObservation as exc:
            why = str(rejection_as_sent(per, t, msg, exc))
            self.rejected_obs += 1
            self.deltas.book.skipped.add(t)
            self.actor.counter.reject(keys.key(self.ctx.run_id, "sense"), why)
            return QState(t, {}, (), {}, rejected=why[:500])
        self.last_observed = t
        return self.codec.message(p)

    async def finish(self) -> dict[str, Any]:
        """After the last step: the qstate log stays open for the learners behind."""
        self.result = await self.actor.finish(CONSUMERS, rejected_observations=self.rejected_obs)
        return self.result


async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    """The perception actor as a task of its own."""
    with PerceptionActor(session, ctx) as perception:
        return await perception.run()
