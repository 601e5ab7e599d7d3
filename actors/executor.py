"""The executor actor: plans, the call list, IAC and babbling (ch. 5–6) -> ``motor(t)``.

It holds the :class:`~qlap_runtime.qlap.agent.Agent` whose learner is a follower: it keeps the
DBN statistics that rel(r, s) needs from the ``qstate`` stream and applies the batch actors'
deltas at step boundaries, but never learns DBNs or landmarks itself. Plan conversion (Algorithm
2 line 15) runs here, right after the deltas are applied, because it reads the executor's own
action and plan statistics (a departure from a separate planner actor, see docs/runtime.md).
Writes checkpoints (with the retention ``ctx.keep_checkpoints``), the metrics log,
``knowledge.json`` and ``summary.json`` like the synchronous loop.

It obeys the UI's commands on ``control`` through the runner contract shared with the
terminal UI's local runner (:mod:`qlap_runtime.runtime.runner`): ``goal`` and ``save`` at a
step boundary (between ``motor(t)`` and ``qstate(t + 1)``), and the clock commands the world
obeys on its own :class:`~qlap_runtime.runtime.controls.RunControl`, so that its ``status``
reports pause and speed (docs/runtime.md, Controls). While no step flows (paused), a side task
applies the commands and publishes the status.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import trio

from qlap_runtime.bus.schema import Motor, PlanRequest, encode
from qlap_runtime.metrics import METRICS_FILE, MetricsLog, summary_of
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import (
    atomic_write_json,
    load_agent,
    save_agent,
    save_final_checkpoint,
    save_step_checkpoint,
)
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.controls import RunControl
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.rules import qstate_rule
from qlap_runtime.runtime.runner import BoundaryCommands, Display, Runner

from .checkpoint_parts import gather_final_parts, keep_on_stall
from .convert import QStateCodec, batch_context, plan_request
from .planner import PlanInbox
from .resume import checkpoint_of

NAME = "executor"
END_MARKER_S = 5.0
"""How long a hosted executor waits for the world's end marker to reach its controls."""


class ExecutorActor(ActorBase):
    """The executor actor: its agent, its inputs and outputs, one step of its loop, its end.

    Standalone (:func:`run`) it is a task of its own. In the embedded placement the world's task
    hosts it after the perception actor (``actors.world.run(..., executor=...)``): the world
    calls :meth:`step` once ``qstate(t)`` went out, which this session already handed to the
    executor's inbox, so the step chain runs in one task without a wake-up. Either way
    :meth:`between_steps` runs beside it (commands and status while no step flows).
    """

    def __init__(self, session: Any, ctx: RunContext, *, hosted: bool = False) -> None:
        specs, _ = world_variables(ctx.world)
        self.ctx, self.hosted = ctx, hosted
        self.t_start = time.perf_counter()
        self.steps_done = 0
        self.actor = actor = Actor(session, ctx, NAME, obey=True)
        resume = actor.resume
        self.checkpoint = checkpoint = checkpoint_of(ctx, resume.path)
        self.agent = agent = load_agent(resume.path) if resume.path is not None \
            else load_agent(checkpoint) if checkpoint is not None \
            else Agent(specs, ctx.params, seed=ctx.seed)
        agent.learner.pending_deltas.clear()    # a resumed run's: refused before the run
        agent.learner.auto_batches = False
        agent.learner.follower = True
        self.rejected: list[str] = list(resume.state.get("rejected", []))
        self.metrics = MetricsLog(Path(ctx.out) / METRICS_FILE, agent, start=resume.step + 1,
                                  every=ctx.metrics_every) if ctx.out is not None else None
        # The last periodic checkpoint: (agent step, agent commands applied by then, its path).
        self.last_saved: tuple[int, int, Path | None] = (-1, -1, None)
        self.codec = QStateCodec(agent.table)
        actor.input("qstate", window=1, rule=qstate_rule(self.codec.names))
        self.deltas = actor.deltas(len(agent.table))
        self.plans = PlanInbox(actor, ctx, self.deltas.book)
        self.motors, self.contexts = actor.output("motor"), actor.output("batchctx")
        self.requests = actor.output("planreq")
        # batchctx(s) of a batch at s + 1 went out before the snapshot at s, so a restarted
        # executor never publishes it again: its snapshot carries the logged ones, served
        # again to a batch actor restarted later from an older snapshot (docs/runtime.md);
        # so for planreq and the planner.
        actor.restore_log(self.contexts, resume.state.get("batchctx", []))
        actor.restore_log(self.requests, resume.state.get("planreq", []))
        hz = ctx.hz if ctx.realtime else 0.0
        self.runner = Runner(agent, ctx.world, clock=RunControl(speed=hz, default_speed=hz),
                             out=ctx.out, counter=actor.counter, key=actor.controls.key,
                             run_id=ctx.run_id)
        self.display = Display(session, ctx.run_id, placement=ctx.placement or "embedded",
                               world=ctx.world, seed=ctx.seed, actor=NAME)
        self.clock_name = "realtime" if ctx.realtime else "lockstep"
        self.commands = BoundaryCommands(actor.controls, self.runner, self.publish)
        self.result: dict[str, Any] | None = None
        self._closed = False
        self._side = trio.CancelScope()

    def publish(self, force: bool) -> None:
        self.display.publish(self.agent, self.runner.clock, clock_name=self.clock_name,
                             force=force)

    async def start(self) -> None:
        """Alive; a resumed run starting on a batch step publishes that batch's context."""
        ctx, agent = self.ctx, self.agent
        await self.actor.start()
        if self.checkpoint is not None and batch_kinds(ctx.params, ctx.start) \
                and ctx.start < ctx.end:
            # A resumed run starting on a batch step: the batch reads the checkpoint's
            # agent (the uninterrupted run's executor published it before motor(N - 1)).
            self.contexts.put(ctx.start - 1, batch_context(agent, ctx.start - 1))
        if self.hosted:
            self.commands.at_boundary = True    # between steps until the world calls step

    async def between_steps(self) -> None:
        """Commands and the status while the step loop waits (run beside the steps, until
        :meth:`finish`)."""
        with self._side:
            await self.commands.between_steps()

    async def step(self, t: int) -> bool:
        """``qstate(t)`` -> ``motor(t)``; False when the run ended before step t."""
        ctx, agent, actor, commands = self.ctx, self.agent, self.actor, self.commands
        commands.apply()
        with commands.waiting():
            msg = await actor.receive(t)
        if msg is None:
            return False
        ask = t in self.plans.asked
        if msg.rejected:
            self.deltas.book.skipped.add(t)
            if ask:
                self.requests.put(t, PlanRequest(t, rejected=True))
            self.rejected.append(f"step {t}: {msg.rejected}")
            motor = Motor(t, dict(agent.motor))
        else:
            # The learner's percept (not the message's): a landmark applied at this step
            # renumbers its q in place, as in the synchronous loop, so the decision reads the
            # current values with the new landmarks. Waited for before observing: a cancel
            # (a stall) leaves the agent at a step boundary, which keep_on_stall saves.
            due = await self.deltas.due_now(t, ctx.realtime)
            lag = ctx.params.batch_lag
            plans = await self.plans.due(t) if lag else []
            p = agent.learner.observe_percept(self.codec.percept(msg))
            if ask:                             # the state the batch at t copies
                self.requests.put(t, plan_request(agent, t))
            for d in due:
                agent.learner.apply_delta(d)
            agent.pending_plans.extend(plans if lag else await self.plans.due(t))
            motor = Motor(t, dict(agent.decide(p)))
        if batch_kinds(ctx.params, t + 1) and t + 1 < ctx.end:
            # Before motor(t): the batch at t + 1 reads this state (§6.2.1).
            self.contexts.put(t, batch_context(agent, t))
        self.motors.put(t, motor)
        actor.slot.done(t)
        self.steps_done += 1
        if self.metrics is not None:
            self.metrics.after_step(t + 1, agent)
        if not msg.rejected:
            self.publish(False)
            if ctx.out is not None and (t + 1) % ctx.checkpoint_every == 0:
                self.last_saved = (agent.step_count, self.runner.agent_changes,
                                   save_step_checkpoint(agent, Path(ctx.out) / "checkpoints",
                                                        t + 1, ctx.world,
                                                        ctx.keep_checkpoints))
        if actor.snapshot_due(t):
            actor.snapshot(t, lambda d: save_agent(agent, d), rejected=self.rejected,
                           batchctx=[[s, encode(m).decode()]
                                     for s, m in self.contexts.log.entries()],
                           planreq=[[s, encode(m).decode()]
                                    for s, m in self.requests.log.entries()])
        if self.hosted:
            commands.at_boundary = True         # the world goes on: commands may apply
        return True

    async def finish(self, quit_at: int | None) -> dict[str, Any]:
        """After the last step (``quit_at``: the world's last step after a ``quit``): the
        final status, knowledge, checkpoint and summary; then stay until the batch actors
        behind are done."""
        ctx, agent, runner = self.ctx, self.agent, self.runner
        if quit_at is not None:
            # The world's end marker is on its way to this actor's controls (a hosted
            # executor ends right after the world published it): the status answers it.
            with trio.move_on_after(END_MARKER_S):
                while self.actor.controls.last_step is None:  # noqa: ASYNC110 - a callback
                    await trio.sleep(0.001)
        self._side.cancel()                     # no command or status from the side now
        self.commands.at_boundary = False
        self.actor.slot.finished()
        self.commands.apply()
        runner.finished = True
        self.display.finish()
        if not runner.message.startswith("run ended"):
            runner.message = f"finished {self.steps_done} steps"
        self.publish(True)
        self._end()
        wall = time.perf_counter() - self.t_start
        self.result = self.actor.result(
            wait_s=round(self.deltas.wait_s, 3), rejected_observations=len(self.rejected),
            rejected_examples=self.rejected[:20], wall_s=wall, steps_done=self.steps_done,
            **({} if quit_at is None else {"quit_at_step": quit_at}))
        if ctx.out is not None:
            out = Path(ctx.out)
            atomic_write_json(out / "knowledge.json", agent.knowledge())
            # final links to the last step-N when nothing changed the agent since (no step, no
            # goal command): the same state, not a copy.
            same = self.last_saved[2] if self.last_saved[:2] == (agent.step_count,
                                                                 runner.agent_changes) else None
            save_final_checkpoint(agent, out / "checkpoints", ctx.world, same_as=same)
            summary = summary_of(agent, type("W", (), {"name": ctx.world})(), ctx.seed,
                                 self.steps_done if quit_at is not None else ctx.steps, wall,
                                 self.rejected)
            atomic_write_json(out / "actors" / f"{NAME}.json", summary)
        # Outputs first (a failed world waits for the other actors' tokens, then reads
        # them); then a batch actor behind may still ask for a lost batch context.
        await self.actor.linger(("contingency", "landmarks", "planner"))
        if ctx.placement == "distributed":      # no launcher: the executor places them
            await gather_final_parts(self.actor.session, ctx)
        return self.result

    def _end(self) -> None:
        """The display and the metrics log end (once)."""
        if self._closed:
            return
        self._closed = True
        self.display.close()
        if self.metrics is not None:
            self.metrics.finish(self.actor.resume.step + 1 + self.steps_done, self.agent)

    def close(self) -> None:
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
