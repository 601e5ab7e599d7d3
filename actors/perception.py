"""The perception actor: ``sense(t)`` -> ``qstate(t)`` with the current landmarks (ch. 3)."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from qlap_runtime.bus import keys
from qlap_runtime.bus.schema import QState, encode
from qlap_runtime.qlap.checkpoint import load_learner
from qlap_runtime.qlap.delta import AddLandmark
from qlap_runtime.qlap.perception import InvalidObservation, Perception
from qlap_runtime.qlap.quantity import Landmark
from qlap_runtime.qlap.variables import VariableTable
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.snapshot import load_perception, save_perception

from .convert import QStateCodec
from .resume import checkpoint_of

NAME = "perception"
CONSUMERS = ("contingency", "landmarks", "executor")


def apply_landmark_ops(per: Perception, deltas) -> None:
    """Mirror the learner's landmark additions (the only ops that change perception)."""
    for delta in deltas:
        for op in delta.ops:
            if isinstance(op, AddLandmark):
                space = per.spaces[int(op.var)]
                if space.landmarks and space.interval_of_range(float(op.lb),
                                                               float(op.ub)) is None:
                    continue                     # the learner skips it too
                per.add_landmark(int(op.var), Landmark(float(op.lb), float(op.ub), int(op.step),
                                                       op.source))


def _as_sent(per: Perception, t: int, msg, exc: InvalidObservation) -> InvalidObservation:
    """The reason the synchronous agent gives: the world actor sends ±inf as ±float max
    (actors/world.py), so the rejection is checked again with them restored (the state is
    unchanged by a rejected observation)."""
    x = per.vector(msg.values)
    huge = np.abs(x) == sys.float_info.max
    if not huge.any():
        return exc
    x[huge] = np.copysign(np.inf, x[huge])
    try:
        per.perceive(t, x, copy=False, discontinuity=msg.discontinuity)
    except InvalidObservation as again:
        return again
    return exc


class PerceptionActor(ActorBase):
    """The perception actor: its state, its inputs and outputs, and one step of its loop.

    Standalone (:func:`run`) it is a task of its own. In the embedded placement the world's task
    hosts it (``actors.world.run(..., perception=...)``): the world calls :meth:`step` right
    after publishing ``sense(t)``, whose message the same session has already handed to this
    actor's inbox, so the step chain wakes two tasks per step (world, executor) instead of
    three. Inputs, rules, replay and snapshots are the same either way.
    """

    def __init__(self, session: Any, ctx: RunContext) -> None:
        specs, _ = world_variables(ctx.world)
        table = VariableTable.from_specs(specs)
        self.ctx = ctx
        self.per, self.codec = Perception(table, ctx.params), QStateCodec(table)
        self.rejected_obs = 0
        self.sense_key = keys.key(ctx.run_id, "sense")
        self.actor = actor = Actor(session, ctx, NAME)
        self.result: dict[str, Any] | None = None
        resume = actor.resume
        checkpoint = checkpoint_of(ctx, resume.path)
        if resume.path is not None:
            load_perception(self.per, resume.path)
        elif checkpoint is not None:            # a resumed run: the learner's perception
            self.per = load_learner(checkpoint).perception
        # On the step chain: sense(t + 1) exists only once qstate(t) went out (window 1;
        # unknown variables are rejected by perceive, as in the synchronous loop).
        actor.input("sense", window=1)
        self.deltas = actor.deltas(len(table))
        self.out = actor.output("qstate")
        actor.restore_log(self.out, resume.state.get("qstate", []))
        self.last_observed = int(resume.state.get("last_observed", ctx.start - 1))

    async def start(self) -> None:
        """Alive (every subscription exists); a restarted actor fetches what it missed."""
        await self.actor.start()

    async def step(self, t: int) -> bool:
        """``sense(t)`` -> ``qstate(t)``; False when the run ended before step t."""
        actor, per, deltas, ctx = self.actor, self.per, self.deltas, self.ctx
        msg = await actor.receive(t)
        if msg is None:
            return False
        last_observed = self.last_observed
        if last_observed >= ctx.start and last_observed > deltas.book.last:
            # Deltas applied at the boundary of the last observed step change the
            # landmarks used from t on.
            apply_landmark_ops(per, await deltas.due_now(last_observed, ctx.realtime))
        try:
            p = per.perceive(t, per.vector(msg.values), copy=False,
                             discontinuity=msg.discontinuity)
        except InvalidObservation as exc:
            exc = _as_sent(per, t, msg, exc)
            self.rejected_obs += 1
            deltas.book.skipped.add(t)
            actor.counter.reject(self.sense_key, str(exc))
            qstate = QState(t, {}, (), {}, rejected=str(exc)[:500])
        else:
            self.last_observed = t
            qstate = self.codec.message(p)
        self.out.put(t, qstate)
        actor.slot.done(t)
        if actor.snapshot_due(t):
            # The qstate log after the oldest consumer snapshot goes with it: a consumer
            # restarted from that snapshot after this actor restarted fetches them from
            # the new process (chaos trials, issue 13).
            since = actor.oldest_snapshot(CONSUMERS) + 1
            actor.snapshot(t, lambda d: save_perception(per, d),
                           last_observed=self.last_observed,
                           qstate=[[s, encode(m).decode()] for s, m in self.out.log.entries(since)])
        return True

    async def finish(self) -> dict[str, Any]:
        """After the last step: keep the qstate log open for the learners behind; the result."""
        self.actor.slot.finished()
        await self.actor.linger(CONSUMERS)      # a learner behind may ask for a lost qstate
        self.result = self.actor.result(rejected_observations=self.rejected_obs)
        return self.result



async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    """The perception actor as a task of its own."""
    with PerceptionActor(session, ctx) as perception:
        await perception.start()
        for t in perception.actor.steps():
            if not await perception.step(t):
                break
        return await perception.finish()
