"""The perception actor: ``sense(t)`` -> ``qstate(t)`` with the current landmarks (ch. 3)."""

from __future__ import annotations

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.schema import QState
from qlap_runtime.qlap.perception import InvalidObservation, Perception
from qlap_runtime.qlap.quantity import Landmark
from qlap_runtime.qlap.variables import VariableTable

from .common import DeltaInbox, RunContext, StepInbox, qstate_of, world_variables

NAME = "perception"


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


async def run(session, ctx: RunContext) -> dict:
    specs, _ = world_variables(ctx.world)
    table = VariableTable.from_specs(specs)
    per = Perception(table, ctx.params)
    counter = RejectionCounter(NAME)
    rejected_obs = 0
    with declare_alive(session, ctx.run_id, NAME), \
            TrioSubscriber(session, keys.key(ctx.run_id, "sense"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, "qstate") as pub:
        deltas = DeltaInbox(session, ctx, counter)
        try:
            inbox = StepInbox(sub)
            start = ctx.extra.get("start_step", 0)
            last_observed = start - 1
            for t in range(start, start + ctx.steps):
                msg = await inbox.get(t)
                if last_observed >= start and last_observed > deltas.book.last:
                    # Deltas applied at the boundary of the last observed step change the
                    # landmarks used from t on.
                    apply_landmark_ops(per, await deltas.due_now(last_observed, ctx.realtime))
                try:
                    p = per.perceive(t, per.vector(msg.values), copy=False)
                except InvalidObservation as exc:
                    rejected_obs += 1
                    deltas.book.skipped.add(t)
                    counter.reject(keys.key(ctx.run_id, "sense"), str(exc))
                    pub.put(QState(t, {}, (), {}, rejected=str(exc)[:500]))
                    continue
                last_observed = t
                pub.put(qstate_of(p, table))
        finally:
            deltas.close()
    return {"rejected": counter.snapshot().total, "rejected_observations": rejected_obs,
            "waits": deltas.book.waits}
