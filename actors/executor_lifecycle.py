"""The executor actor's life around its step (:mod:`actors.executor`): its start, the commands
between steps, what follows each step (status, files, batch copies' statistics, snapshots) and
the end of the run — the final status and files, then staying until the actors behind are
done; on a stall or a cancellation, what the run keeps. A base class of
:class:`~actors.executor.ExecutorActor`, kept apart so that the actor's module reads receive ->
algorithm -> publish."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import trio

from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import save_agent
from qlap_runtime.qlap.perception import Percept
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.inbox import DeltaInbox

from .chain import Chain
from .checkpoint_parts import gather_final_parts, keep_on_stall
from .executor_parts import BatchLinks, Controls, Files
from .handover import HandOver

END_MARKER_S = 5.0
"""How long a hosted executor waits for the world's end marker to reach its controls."""


class ExecutorLifecycle(ActorBase):
    """The executor's :meth:`start`, :meth:`between_steps`, :meth:`after_step`, :meth:`finish`,
    :meth:`close` and context exit (the fields are the executor's)."""

    ctx: RunContext
    actor: Actor
    agent: Agent
    handover: HandOver
    controls: Controls
    files: Files
    deltas: DeltaInbox
    steps_done: int
    checkpoint: Path | None
    links: BatchLinks
    chain: Chain | None

    async def start(self) -> None:
        await self.actor.start()
        self.links.prepare(self.agent)
        if self.checkpoint is not None:
            self.links.resumed(self.agent)
        if self.chain is not None:      # between steps until the world calls step
            self.controls.commands.at_boundary = True

    async def between_steps(self) -> None:
        """Commands and the status while the step loop waits (until :meth:`finish`)."""
        await self.controls.between_steps()

    def after_step(self, t: int, p: Percept | None) -> None:
        """After ``motor(t)``: the status, the files, the statistics part, the snapshot; then
        commands may apply (the world goes on)."""
        actor, agent = self.actor, self.agent
        actor.slot.done(t)
        self.steps_done += 1
        if p is not None:
            self.controls.publish(False)
        self.files.after_step(t, p, self.controls.runner.agent_changes)
        self.handover.after_step(t, agent.learner)
        if actor.snapshot_due(t):
            actor.snapshot(t, lambda d: save_agent(agent, d),
                           rejected=self.files.rejected.to_state(), **self.links.logs())
        if self.chain is not None:
            self.controls.commands.at_boundary = True

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


async def end_marker(actor: Actor) -> None:
    """After a ``quit``: wait (a little) until the world's end marker reached the actor's
    controls (a hosted executor ends right after the world published it)."""
    with trio.move_on_after(END_MARKER_S):
        while actor.controls.last_step is None:  # noqa: ASYNC110 - set by a callback
            await trio.sleep(0.001)
