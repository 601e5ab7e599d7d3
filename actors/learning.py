"""The two batch-learning actors (Algorithm 2 lines 6–13), sharing one implementation.

Both keep a :class:`~qlap_runtime.qlap.learner.ModelLearner` from the ``qstate`` stream and apply
every delta at its step boundary: replicas of the synchronous loop's learner. ``contingency``
computes lines 6–9 at every DBN batch (``delta/dbn``); ``landmarks`` computes lines 6–9 on its
own copy, then 10–13 (``delta/landmarks``). How a batch runs is :mod:`~qlap_runtime.runtime.
batches`'; two sharing a process run in one task (:mod:`actors.learning_pair`).
"""

from __future__ import annotations

from typing import Any

from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.qlap.variables import VariableTable
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.batches import Batches
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.inbox import DeltaInbox
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.rules import qstate_rule
from qlap_runtime.runtime.snapshot import save_learner_snapshot
from qlap_runtime.runtime.start_state import start_learner

from .checkpoint_parts import final_dir, part_dir, save_statistics_part
from .convert import QStateCodec, apply_batch_context

ROLES = {"contingency": "dbn", "landmarks": "landmarks"}
CONSUMERS = ("perception", "contingency", "landmarks", "executor")
"""Every actor that applies deltas."""


class LearnerActor(ActorBase):
    """One batch-learning actor (``role`` contingency or landmarks); a step is
    :meth:`observe` (lines 2–5), :meth:`batch` (6–9 or 6–13 on a copy), :meth:`settle`.

    ``shared``: the learner of the contingency actor that hosts this one's steps
    (:func:`~actors.learning_pair.run_pair`): the host observes and applies the deltas, this
    guest only takes its messages (its rules and books as standalone) and publishes its part
    of the batches. ``handed``: neither a learner nor the ``qstate`` and delta inputs
    (:func:`~actors.learning_pair.run_handed`).
    """

    def __init__(self, session: Any, ctx: RunContext, role: str,
                 shared: ModelLearner | None = None, *, handed: bool = False) -> None:
        if role not in ROLES:
            raise ValueError(f"unknown learning role {role!r}; expected {sorted(ROLES)}")
        ctx = ctx.for_actor(role)                       # its own snapshot in a group
        self.ctx, self.role, self.kind, self.guest = ctx, role, ROLES[role], shared is not None
        self.actor = actor = Actor(session, ctx, role)
        if handed:
            n = len(VariableTable.from_specs(world_variables(ctx.world)[0]))
            self.batches = Batches(actor, self.kind, n)
            return
        self.learner = shared if shared is not None else start_learner(ctx, actor.resume)
        self.codec = QStateCodec(self.learner.table)
        n = len(self.learner.table)
        actor.input("qstate", window=ctx.replay_keep, rule=qstate_rule(self.codec.names))
        self.batches = Batches(actor, self.kind, n)     # batchctx in, delta/<kind> out
        self.deltas: DeltaInbox | None = actor.deltas(n)
        self._msg: Any = None

    learner: ModelLearner | None = None
    """None when handed (:func:`~actors.learning_pair.run_handed`)."""
    deltas: DeltaInbox | None = None

    async def start(self) -> None:
        await self.actor.start()
        if self.deltas is not None:
            self.batches.out.requeue(self.deltas)       # its own deltas not yet applied here

    async def step(self, t: int) -> bool:
        if not await self.observe(t):
            return False
        await self.batch(t)
        await self.settle(t)
        return True

    async def observe(self, t: int) -> bool:
        """Take ``qstate(t)`` and learn from it (unless a guest: its host did)."""
        self._msg = msg = await self.actor.receive(t, lazy=not self.guest)
        if msg is None:
            return False
        if msg.rejected:
            self.deltas.book.skipped.add(t)
        elif not self.guest:
            self.learner.observe_percept(self.codec.percept(msg))
        return True

    async def batch(self, t: int, guest: LearnerActor | None = None) -> None:
        """This actor's batch at ``t``, if one starts there. ``guest`` (the landmarks actor on
        this learner, at its batch step): its lines 10–13 on the same copy, right after these
        lines 6–9, as the standalone landmarks actor computes them on its identical copy."""
        if not self._msg.rejected and self.kind in batch_kinds(self.ctx.params, t):
            await self.batches.begin(t, self.learner, self.nursery, apply_batch_context,
                                     None if guest is None else guest.batches)

    async def settle(self, t: int, guest: LearnerActor | None = None) -> None:
        """The deltas due at ``t`` (applied unless a guest), the checkpoint's statistics part
        and the snapshot. A guest writes its snapshot with its host's (``guest``, after the
        guest's own ``settle(t)``): at the same steps, the guest's first, so that a restarted
        pair finds both at one step (``snapshot.common_snapshot``)."""
        actor, learner = self.actor, self.learner
        if not self._msg.rejected:
            for d in await self.deltas.due_now(t, self.ctx.realtime):
                if not self.guest:
                    learner.apply_delta(d)
        actor.slot.done(t)
        if self.role == "contingency":          # the executor's checkpoint's part
            save_statistics_part(part_dir(self.ctx, t), learner)
        if self.guest or not self.batches.out.snapshot_now(t):
            return
        if guest is not None:                   # the learner's files are the host's
            guest.batches.out.write_snapshot(t, None, CONSUMERS)
        self.batches.out.write_snapshot(t, lambda d: save_learner_snapshot(learner, d),
                                       CONSUMERS)

    async def finish(self) -> dict[str, Any]:
        """The final statistics part; stay until the consumers are done (a consumer behind
        may ask for a lost delta)."""
        if self.role == "contingency" and self.learner is not None:
            save_statistics_part(final_dir(self.ctx), self.learner)
        self.result = await self.actor.finish(CONSUMERS, **self.batches.result())
        return self.result


async def run(session: Any, ctx: RunContext, role: str) -> dict[str, Any]:
    """One learning actor as a task of its own."""
    with LearnerActor(session, ctx, role) as me:
        return await me.run()
