"""The perception actor: ``sense(t)`` -> ``qstate(t)`` with the current landmarks (ch. 3)."""

from __future__ import annotations

import sys

import numpy as np

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.replay import ReplayLog
from qlap_runtime.bus.schema import QState, decode, encode
from qlap_runtime.qlap.perception import InvalidObservation, Perception
from qlap_runtime.qlap.quantity import Landmark
from qlap_runtime.qlap.variables import VariableTable
from qlap_runtime.runtime.snapshot import load_perception, save_perception
from qlap_runtime.runtime.watchdog import slot_of

from .common import (
    Controls,
    DeltaInbox,
    Resume,
    RunContext,
    RunEnded,
    StepInbox,
    oldest_consumer_snapshot,
    qstate_of,
    resume_inputs,
    snapshot_due,
    snapshot_stats,
    world_variables,
    write_snapshot,
)

NAME = "perception"
CONSUMERS = ("contingency", "landmarks", "executor")


def apply_landmark_ops(per: Perception, deltas) -> None:
    """Mirror the learner's landmark additions (the only ops that change perception)."""
    for delta in deltas:
        for op in delta.ops:
            if op[0] == "add_landmark":
                _, var, lb, ub, source, step = op[:6]
                space = per.spaces[int(var)]
                if space.landmarks and space.interval_of_range(float(lb), float(ub)) is None:
                    continue                     # the learner skips it too
                per.add_landmark(int(var), Landmark(float(lb), float(ub), int(step), source))


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


async def run(session, ctx: RunContext) -> dict:
    specs, _ = world_variables(ctx.world)
    table = VariableTable.from_specs(specs)
    per = Perception(table, ctx.params)
    counter = RejectionCounter(NAME)
    rejected_obs = 0
    resume = Resume.of(ctx, NAME)
    if resume.path is not None:
        load_perception(per, resume.path)
    snapshot_s: list[float] = []
    with declare_alive(session, ctx.run_id, NAME), \
            TrioSubscriber(session, keys.key(ctx.run_id, "sense"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, "qstate") as pub, \
            ReplayLog(session, ctx.run_id, "qstate", ctx.replay_keep) as replay, \
            Controls(session, ctx, counter, keep=False) as end:   # the world's end marker
        slot = slot_of(ctx, NAME)
        deltas = DeltaInbox(session, ctx, counter, slot, n_vars=len(table))
        qkey = keys.key(ctx.run_id, "qstate")
        for step, payload in resume.state.get("qstate", []):
            replay.append(int(step), decode(qkey, payload))
        try:
            # On the step chain: sense(t + 1) exists only once qstate(t) went out (window 1;
            # unknown variables are rejected by perceive, as in the synchronous loop).
            inbox = StepInbox(sub, first=resume.step + 1, end=end, slot=slot, topic="sense",
                              counter=counter, key=keys.key(ctx.run_id, "sense"),
                              window=None if ctx.realtime else 1)
            await resume_inputs(session, ctx, resume, inbox, "sense", deltas, counter)
            start = ctx.start
            last_observed = int(resume.state.get("last_observed", start - 1))
            for t in range(resume.step + 1, start + ctx.steps):
                try:
                    msg = await inbox.get(t)
                except RunEnded:                    # quit: the world took no step t
                    break
                if last_observed >= start and last_observed > deltas.book.last:
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
                    counter.reject(keys.key(ctx.run_id, "sense"), str(exc))
                    out = QState(t, {}, (), {}, rejected=str(exc)[:500])
                else:
                    last_observed = t
                    out = qstate_of(p, table)
                pub.put(out)
                replay.append(t, out)
                slot.done(t)
                if snapshot_due(ctx, t):
                    # The qstate log after the oldest consumer snapshot goes with it: a
                    # consumer restarted from that snapshot after this actor restarted fetches
                    # them from the new process (chaos trials, issue 13).
                    since = oldest_consumer_snapshot(ctx, CONSUMERS) + 1
                    snapshot_s.append(write_snapshot(
                        ctx, NAME, t, deltas, lambda d: save_perception(per, d),
                        last_observed=last_observed,
                        qstate=[[s, encode(m).decode()] for s, m in replay.entries(since)]))
            slot.finished()
        finally:
            deltas.close()
    return {"rejected": counter.snapshot().total, "rejected_observations": rejected_obs,
            "waits": deltas.book.waits, **snapshot_stats(snapshot_s, resume)}
