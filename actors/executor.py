"""The executor actor: plans, the call list, IAC and babbling (ch. 5–6) -> ``motor(t)``.

Its agent's learner is a follower (DBN statistics from ``qstate``, the batch actors' deltas at
step boundaries). At each batch step it publishes its agent for the planner (``planreq``) and
applies the plan delta at t + L after the batch's deltas; Sarsa and Dyna stay here
(docs/decisions.md 56). With the learners in its process and a lag, it hands them their batch
copies (:mod:`actors.handover`, docs/decisions.md 72). Controls, display and files:
:mod:`actors.executor_parts`.
"""

from __future__ import annotations

from typing import Any

import trio

from qlap_runtime.bus.schema import Motor
from qlap_runtime.qlap.checkpoint import save_agent
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.rules import qstate_rule

from .chain import Chain
from .checkpoint_parts import gather_final_parts, keep_on_stall
from .convert import QStateCodec
from .executor_parts import BatchLinks, Controls, Files, end_marker, load_executor_agent
from .handover import HandOver

NAME = "executor"


class ExecutorActor(ActorBase):
    """The executor actor. Standalone (:func:`run`) it is a task of its own; on the hosted
    step chain (``chain``) the world's task calls :meth:`step` after the perception actor's,
    which perceived step t with this agent's learner's perception (decision 83), and takes
    ``motor(t)`` from the chain. Either way :meth:`between_steps` runs beside it."""

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

    async def start(self) -> None:
        await self.actor.start()
        if self.checkpoint is not None:
            self.links.resumed(self.agent)
        if self.chain is not None:      # between steps until the world calls step
            self.controls.commands.at_boundary = True

    async def between_steps(self) -> None:
        """Commands and the status while the step loop waits (until :meth:`finish`)."""
        await self.controls.between_steps()

    async def step(self, t: int) -> bool:
        """``qstate(t)`` -> ``motor(t)``; False when the run ended before step t."""
        ctx, agent, actor, commands = self.ctx, self.agent, self.actor, self.controls.commands
        commands.apply()
        chain, p, msg = self.chain, None, None
        if chain is None:
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
            self.files.rejected.append(f"step {t}: {rejected}")
            self.handover.observed(t, None)                 # no batch at t
            motor = Motor(t, dict(agent.motor))
        else:
            # The learner's percept: a landmark applied at t renumbers its q in place, as in
            # the sync loop. Deltas waited for before observing (a stall: a step boundary).
            due = await self.deltas.due_now(t, ctx.realtime)
            plans = await self.links.plans.due(t) if ctx.params.batch_lag else None
            if msg is not None:                 # from the bus
                p = agent.learner.observe_percept(self.codec.percept(msg))
            elif chain is not None and chain.percept is not None and chain.percept.step == t:
                p = agent.learner.observe_own(chain.percept)
            else:
                raise RuntimeError(f"the hosted step chain has no percept of step {t}")
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
        actor.slot.done(t)
        self.steps_done += 1
        if p is not None:
            self.controls.publish(False)
        self.files.after_step(t, p, self.controls.runner.agent_changes)
        self.handover.after_step(t, agent.learner)
        if actor.snapshot_due(t):
            actor.snapshot(t, lambda d: save_agent(agent, d), rejected=self.files.rejected,
                           **self.links.logs())
        if self.chain is not None:
            commands.at_boundary = True         # the world goes on: commands may apply
        return True

    async def finish(self, quit_at: int | None) -> dict[str, Any]:
        """After the last step (``quit_at``: the world's last step after a ``quit``): the
        final status and files; then stay until the actors behind are done."""
        self.files.flush()                      # the last step's checkpoint, as it was
        self.handover.end(self.actor.resume.step + self.steps_done)
        if quit_at is not None:                 # the status answers the world's end marker
            await end_marker(self.actor)
        self.actor.slot.finished()
        self.controls.last(self.steps_done)
        self._end()
        self.result = self.actor.result(wait_s=round(self.deltas.wait_s, 3),
                                        **self.files.result(self.steps_done, quit_at))
        self.files.final(self.steps_done if quit_at is not None else self.ctx.steps,
                         self.controls.runner.agent_changes)
        self.handover.final(self.agent.learner)
        # Outputs first; then an actor behind may still ask for a lost context or request.
        await self.actor.linger(("contingency", "landmarks", "planner"))
        if self.ctx.placement == "distributed":  # no launcher: the executor places them
            await gather_final_parts(self.actor.session, self.ctx)
        return self.result

    def _end(self) -> None:
        self.controls.close()                   # once each
        self.files.close(self.actor.resume.step + 1 + self.steps_done)

    def close(self) -> None:
        self.handover.end(self.actor.resume.step + self.steps_done)
        self._end()
        self.actor.close()

    def __exit__(self, exc_type: Any, *exc: object) -> None:
        if exc_type is not None:                # cancelled (maybe in a group) by a stall
            keep_on_stall(self.ctx, self.agent)  # a stalled run keeps what was learned
        self.close()


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
