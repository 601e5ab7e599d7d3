"""The executor actor: plans, the call list, IAC and babbling (ch. 5–6) -> ``motor(t)``.

Its agent's learner is a follower (DBN statistics from ``qstate``, the batch actors' deltas at
step boundaries). At each batch step it publishes its agent for the planner (``planreq``) and
applies the plan delta at t + L after the batch's deltas; Sarsa and Dyna stay here
(docs/decisions.md 56). With the learners in its process and a lag, it hands them their batch
copies (:mod:`actors.handover`, docs/decisions.md 72). Controls, display and files:
:mod:`actors.executor_parts`; start, after each step and end: :mod:`actors.executor_lifecycle`.
"""

from __future__ import annotations

from typing import Any

import trio

from qlap_runtime.bus.schema import Motor
from qlap_runtime.runtime.actor import Actor
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.rules import qstate_rule

from .chain import Chain
from .convert import QStateCodec
from .executor_lifecycle import ExecutorLifecycle
from .executor_parts import BatchLinks, Controls, Files, load_executor_agent
from .handover import HandOver

NAME = "executor"


class ExecutorActor(ExecutorLifecycle):
    """The executor actor. Standalone (:func:`run`) it is a task of its own; on the hosted
    step chain (``chain``) the world's task calls :meth:`step` after the perception actor's,
    which perceived step t with this agent's learner's perception (decision 83), and takes
    ``motor(t)`` from the chain. Either way :meth:`between_steps` runs beside it. Its start,
    what follows each step and its end: :class:`~actors.executor_lifecycle.ExecutorLifecycle`."""

    def __init__(self, session: Any, ctx: RunContext, *, chain: Chain | None = None) -> None:
        self.ctx, self.chain, self.steps_done = ctx, chain, 0
        hosted = chain is not None
        self.actor = actor = Actor(session, ctx, NAME, obey=True)
        self.agent, self.checkpoint = load_executor_agent(ctx, actor.resume)
        agent = self.agent
        self.handover = HandOver(ctx, agent.learner)    # decision 72
        self.codec = QStateCodec(agent.table)
        self.inbox = actor.input("qstate", window=1, rule=qstate_rule(self.codec.names),
                                 hosted=hosted)
        self.deltas = actor.deltas(len(agent.table))
        self.links = BatchLinks(actor, ctx, self.deltas.book)
        self.motors = actor.output("motor", logged=not hosted)   # hosted: the world's
        self.controls = Controls(session, ctx, agent, actor)
        self.files = Files(ctx, agent, actor.resume)
        self.result: dict[str, Any] | None = None

    async def step(self, t: int) -> bool:
        """``qstate(t)`` -> ``motor(t)``; False when the run ended before step t."""
        ctx, agent, actor, commands = self.ctx, self.agent, self.actor, self.controls.commands
        commands.apply()
        chain, p, msg = self.chain, None, None
        if chain is None:                       # from the bus
            with commands.waiting():
                msg = await actor.receive(t)
            if msg is None:
                return False
            rejected = msg.rejected
        else:                                   # perceived with the learner's perception
            self.inbox.discard(t)               # the rules on anything else that came
            rejected = chain.rejected
        if rejected:
            self.deltas.book.skipped.add(t)
            self.links.rejected(t)
            self.files.rejected.add(f"step {t}: {rejected}")
            self.handover.observed(t, None)                 # no batch at t
            motor = Motor(t, dict(agent.motor))
        else:
            # The learner's percept: a landmark applied at t renumbers its q in place, as in
            # the sync loop. Deltas waited for before observing (a stall: a step boundary).
            due = await self.deltas.due_now(t, ctx.realtime)
            plans = await self.links.plans.due(t) if ctx.params.batch_lag else None
            p = agent.learner.observe_percept(self.codec.percept(msg)) if msg is not None \
                else agent.learner.observe_own(chain.percept_of(t))     # type: ignore[union-attr]
            # The state the batch at t copies, and the plan compilation of t reads.
            self.links.observed(agent, t, self.handover.observed(t, agent.learner))
            for d in due:
                agent.learner.apply_delta(d)
            agent.pending_plans.extend(plans if plans is not None
                                       else await self.links.plans.due(t))
            motor = Motor(t, dict(agent.decide(p)))
        self.links.decided(agent, t)
        self.motors.put(t, motor)
        if chain is not None:
            chain.motor = motor
        self.after_step(t, p)
        return True


async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    """The executor actor as a task of its own."""
    with ExecutorActor(session, ctx) as executor:
        await executor.start()
        async with trio.open_nursery() as nursery:
            nursery.start_soon(executor.between_steps)
            for t in executor.actor.steps():
                if not await executor.step(t):
                    break
            nursery.cancel_scope.cancel()
        return await executor.finish(executor.actor.controls.last_step)
