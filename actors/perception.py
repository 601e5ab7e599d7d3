"""The perception actor: ``sense(t)`` -> ``qstate(t)`` with the current landmarks (ch. 3).

Standalone (:func:`run`) it is a task of its own. On the hosted step chain (the embedded
placement, the processes placement's default groups) the world's task calls
:meth:`PerceptionActor.step` right after ``sense(t)`` (docs/decisions.md 52); the actor then
takes ``sense(t)`` from the :class:`~actors.chain.Chain` and perceives with the executor's
learner's own perception, which the executor then learns from without perceiving again
(decision 83). It publishes ``qstate`` as binary records of the percept's arrays (decision
98). Its skeleton — inputs, rules, replay log, snapshots — is
:mod:`qlap_runtime.runtime.actor`'s.
"""

from __future__ import annotations

from typing import Any

from qlap_runtime.bus import keys
from qlap_runtime.bus.schema import Sense
from qlap_runtime.qlap.perception import InvalidObservation, Percept, Perception
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.batches import hands_over
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.snapshot import save_perception
from qlap_runtime.runtime.start_state import start_perception

from .chain import Chain
from .convert import QStateCodec, apply_landmark_ops, rejection_as_sent

NAME = "perception"
CONSUMERS = ("contingency", "landmarks", "executor")


class PerceptionActor(ActorBase):
    """The perception actor: its quantity spaces, inputs and outputs, one step of its loop."""

    def __init__(self, session: Any, ctx: RunContext, chain: Chain | None = None,
                 shared: Perception | None = None) -> None:
        """``chain``: hosted on the step chain, perceiving with ``shared``, the executor's
        learner's perception, whose landmarks that learner's deltas change (decision 83)."""
        self.ctx, self.chain = ctx, chain
        self.actor = actor = Actor(session, ctx, NAME)
        self.per = shared if shared is not None else start_perception(ctx, actor.resume)
        self.codec = QStateCodec(self.per.table)
        self.rejected_obs = 0
        # On the step chain: sense(t + 1) exists only once qstate(t) went out (window 1;
        # unknown variables are rejected by perceive, as in the synchronous loop).
        self.inbox = actor.input("sense", window=1, hosted=chain is not None)
        self.deltas = actor.deltas(len(self.per.table))
        # Logged while a consumer may ask for a qstate again: the learners, unless the
        # executor hands them their batches (then nobody but a listener reads it).
        # On the hosted chain in lockstep other sessions (the learners of the processes
        # placement) take qstate in bundles (docs/decisions.md 91).
        self.out = actor.output("qstate", logged=chain is None or not hands_over(ctx),
                                bundled=chain is not None and not ctx.realtime)
        actor.restore_log(self.out, actor.resume.state.get("qstate", []))
        self.last_observed = int(actor.resume.state.get("last_observed", ctx.start - 1))

    async def step(self, t: int) -> bool:
        """``sense(t)`` -> ``qstate(t)``; False when the run ended before step t."""
        actor, ctx, chain = self.actor, self.ctx, self.chain
        if chain is None:
            msg = await actor.receive(t)
            if msg is None:
                return False
        else:
            msg = chain.sense
            assert msg is not None
            assert msg.step == t
            self.inbox.discard(t)               # the rules on anything else that came
        seen = self.last_observed
        if seen >= ctx.start and seen > self.deltas.book.last:
            # Deltas applied at the boundary of the last observed step change the landmarks
            # used from t on (hosted: the executor's learner applied them to `per`).
            due = await self.deltas.due_now(seen, ctx.realtime)
            if chain is None:
                apply_landmark_ops(self.per, due)
        p, rejected = self.perceive(t, msg)
        if chain is not None:
            chain.perceived(p, rejected)
        if p is None or self.out.wanted:        # a binary record (docs/decisions.md 98)
            self.out.put(t, self.codec.rejected(t, rejected) if p is None
                         else self.codec.record(p))
        else:
            self.out.skip()
        actor.slot.done(t)
        if actor.snapshot_due(t):
            # The qstate log after the oldest consumer snapshot goes with it: a consumer
            # restarted from that snapshot after this actor restarted fetches them from the
            # new process (chaos trials, issue 13).
            since = actor.oldest_snapshot(CONSUMERS) + 1
            actor.snapshot(t, lambda d: save_perception(self.per, d),
                           last_observed=self.last_observed, qstate=self.out.saved(since))
        return True

    def perceive(self, t: int, msg: Sense) -> tuple[Percept | None, str]:
        """The percept of ``sense(t)``, or why it is rejected (every actor skips t)."""
        per = self.per
        try:
            p = per.perceive(t, per.vector(msg.values), copy=False,
                             discontinuity=msg.discontinuity)
        except InvalidObservation as exc:
            why = str(rejection_as_sent(per, t, msg, exc))
            self.rejected_obs += 1
            self.deltas.book.skipped.add(t)
            self.actor.counter.reject(keys.key(self.ctx.run_id, "sense"), why)
            return None, why[:500]
        self.last_observed = t
        return p, ""

    async def finish(self) -> dict[str, Any]:
        """After the last step: the qstate log stays open for the learners behind."""
        self.out.flush()
        self.result = await self.actor.finish(CONSUMERS, rejected_observations=self.rejected_obs)
        return self.result


async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    """The perception actor as a task of its own."""
    with PerceptionActor(session, ctx) as perception:
        return await perception.run()
