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
from qlap_runtime.runtime.actor import Actor
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


async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    specs, _ = world_variables(ctx.world)
    table = VariableTable.from_specs(specs)
    per, codec = Perception(table, ctx.params), QStateCodec(table)
    rejected_obs = 0
    sense_key = keys.key(ctx.run_id, "sense")
    with Actor(session, ctx, NAME) as actor:
        resume = actor.resume
        checkpoint = checkpoint_of(ctx, resume.path)
        if resume.path is not None:
            load_perception(per, resume.path)
        elif checkpoint is not None:            # a resumed run: the learner's perception
            per = load_learner(checkpoint).perception
        # On the step chain: sense(t + 1) exists only once qstate(t) went out (window 1;
        # unknown variables are rejected by perceive, as in the synchronous loop).
        actor.input("sense", window=1)
        deltas = actor.deltas(len(table))
        out = actor.output("qstate")
        actor.restore_log(out, resume.state.get("qstate", []))
        await actor.start()
        last_observed = int(resume.state.get("last_observed", ctx.start - 1))
        for t in actor.steps():
            msg = await actor.receive(t)
            if msg is None:
                break
            if last_observed >= ctx.start and last_observed > deltas.book.last:
                # Deltas applied at the boundary of the last observed step change the
                # landmarks used from t on.
                apply_landmark_ops(per, await deltas.due_now(last_observed, ctx.realtime))
            try:
                p = per.perceive(t, per.vector(msg.values), copy=False,
                                 discontinuity=msg.discontinuity)
            except InvalidObservation as exc:
                exc = _as_sent(per, t, msg, exc)
                rejected_obs += 1
                deltas.book.skipped.add(t)
                actor.counter.reject(sense_key, str(exc))
                qstate = QState(t, {}, (), {}, rejected=str(exc)[:500])
            else:
                last_observed = t
                qstate = codec.message(p)
            out.put(t, qstate)
            actor.slot.done(t)
            if actor.snapshot_due(t):
                # The qstate log after the oldest consumer snapshot goes with it: a consumer
                # restarted from that snapshot after this actor restarted fetches them from
                # the new process (chaos trials, issue 13).
                since = actor.oldest_snapshot(CONSUMERS) + 1
                actor.snapshot(t, lambda d: save_perception(per, d),
                               last_observed=last_observed,
                               qstate=[[s, encode(m).decode()] for s, m in out.log.entries(since)])
        actor.slot.finished()
        await actor.linger(CONSUMERS)           # a learner behind may ask for a lost qstate
    return actor.result(rejected_observations=rejected_obs)
