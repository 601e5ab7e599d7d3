"""The executor actor's parts besides its step (``actors/executor.py``): where its agent comes
from, what it tells the batch actors and the planner, its controls and display, and its files.

- :func:`load_executor_agent`: a snapshot's agent, a resumed run's checkpoint's, or a fresh one;
  its learner a follower (docs/runtime.md).
- :class:`BatchLinks`: ``batchctx`` for the batch actors (§6.2.1), ``planreq`` for the planner
  and the plan deltas it answers (:class:`PlanInbox`; Algorithm 2 line 15, docs/decisions.md
  56), with their replay logs kept in the executor's snapshots.
- :class:`Controls`: the runner contract shared with the terminal UI's local runner
  (:mod:`qlap_runtime.runtime.runner`): commands at step boundaries and the display topics.
- :class:`Files`: the metrics log, periodic checkpoints, and ``knowledge.json``, the final
  checkpoint and the summary at the end, as the synchronous loop writes them.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import trio

from qlap_runtime.bus.schema import PlanRequest
from qlap_runtime.metrics import METRICS_FILE, MetricsLog, Rejections, summary_of
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import (
    atomic_write_json,
    load_agent,
    save_final_checkpoint,
    step_name,
)
from qlap_runtime.qlap.learner import ModelLearner
from qlap_runtime.qlap.perception import Percept
from qlap_runtime.qlap.plan_delta import PlanDelta
from qlap_runtime.runtime.actor import Actor, Resume
from qlap_runtime.runtime.background import CheckpointWriter
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.controls import RunControl
from qlap_runtime.runtime.lockstep import DeltaBook, batch_kinds
from qlap_runtime.runtime.rules import plan_delta_rule
from qlap_runtime.runtime.runner import BoundaryCommands, Display, Runner

from .convert import LOCAL, batch_context, plan_request
from .planner import compiled_steps
from .resume import checkpoint_of


def load_executor_agent(ctx: RunContext, resume: Resume) -> tuple[Agent, Path | None]:
    """The executor's agent (its learner a follower: statistics, no batches) and the resumed
    run's checkpoint it came from, if any."""
    checkpoint = checkpoint_of(ctx, resume.path)
    agent = load_agent(resume.path) if resume.path is not None \
        else load_agent(checkpoint) if checkpoint is not None \
        else Agent(world_variables(ctx.world)[0], ctx.params, seed=ctx.seed)
    agent.learner.pending_deltas.clear()    # a resumed run's: refused before the run
    agent.pending_plans.clear()
    agent.learner.auto_batches = False
    agent.learner.follower = True
    return agent, checkpoint


class PlanInbox:
    """The executor's side: the steps at which it asks for a compilation (``asked``) and the
    plan deltas due at a step (waited for in lockstep; under the realtime clock those that
    have arrived). ``book``: the executor's delta book, whose skipped steps have no batch."""

    def __init__(self, actor: Actor, ctx: RunContext, book: DeltaBook) -> None:
        self.ctx, self.book = ctx, book
        # A restarted executor still applies the deltas of batches before its snapshot.
        first = max(ctx.start, actor.resume.step + 1 - ctx.params.batch_lag)
        self.asked = set(compiled_steps(ctx, first - 1))
        self.inbox = actor.input("delta/plans", window=ctx.replay_keep, first=first,
                                 rule=plan_delta_rule(ctx.params, ctx.realtime))

    async def due(self, t: int) -> list[PlanDelta]:
        if self.ctx.realtime:
            self.inbox.drain()
            arrived = sorted(self.inbox.buf)
            out = [self.inbox.buf[s].to_delta() for s in arrived]
            for s in arrived:
                self.inbox.drop(s)
            return out
        c = t - self.ctx.params.batch_lag
        if c not in self.asked or c in self.book.skipped:
            return []
        return [(await self.inbox.get(c, at=t)).to_delta()]


class BatchLinks:
    """What the executor tells the batch actors and the planner, and the plan deltas."""

    def __init__(self, actor: Actor, ctx: RunContext, book: DeltaBook) -> None:
        self.ctx = ctx
        self.plans = PlanInbox(actor, ctx, book)
        self.contexts, self.requests = actor.output("batchctx"), actor.output("planreq")
        # batchctx(s) of a batch at s + 1 and planreq(s) went out before the snapshot at s,
        # so a restarted executor never publishes them again: its snapshot carries the
        # logged ones, served again to an actor restarted later from an older snapshot.
        actor.restore_log(self.contexts, actor.resume.state.get("batchctx", []))
        actor.restore_log(self.requests, actor.resume.state.get("planreq", []))

    def resumed(self, agent: Agent) -> None:
        """A resumed run starting on a batch step N: that batch reads the checkpoint's agent
        (the uninterrupted run's executor published it before motor(N − 1))."""
        ctx = self.ctx
        if batch_kinds(ctx.params, ctx.start) and ctx.start < ctx.end:
            self.contexts.put(ctx.start - 1, batch_context(agent, ctx.start - 1))

    def prepare(self, agent: Agent) -> None:
        """Before the first step: under the realtime clock with the planner in this process,
        the buffers its light requests copy the learner's large arrays into (decision 103)."""
        if self.ctx.realtime and self.ctx.together("executor", "planner"):
            LOCAL.prepare(agent.learner)

    def rejected(self, t: int) -> None:
        if t in self.plans.asked:
            self.requests.put(t, PlanRequest(t, rejected=True))

    def observed(self, agent: Agent, t: int, batch: ModelLearner | None = None) -> None:
        """After observing ``qstate(t)``, before the deltas due at t: the state the batch at
        t copies, which the planner compiles (on ``batch``, the learners' copy, when the
        batch computes on it here: docs/decisions.md 86)."""
        if t in self.plans.asked:
            # The planner in this process (RunContext.groups): the agent in memory.
            self.requests.put(t, LOCAL.put(self.ctx.run_id, agent, t, self.ctx.realtime, batch)
                              if self.ctx.together("executor", "planner")
                              else plan_request(agent, t))

    def decided(self, agent: Agent, t: int) -> None:
        """Before ``motor(t)``: the batch at t + 1 reads this state (§6.2.1); after the last
        step the planner is told it is done."""
        if batch_kinds(self.ctx.params, t + 1) and t + 1 < self.ctx.end:
            self.contexts.put(t, batch_context(agent, t))
        if t == self.ctx.end - 1 and t not in self.plans.asked:
            self.requests.put(t, PlanRequest(t, last=True))

    def logs(self) -> dict[str, list]:
        """The replay logs a snapshot keeps."""
        return {name: out.saved()
                for name, out in (("batchctx", self.contexts), ("planreq", self.requests))}


class Controls:
    """The runner contract (controls, goals, saves) and the display topics of the executor;
    while no step flows (paused), a side task applies the commands and publishes the
    status."""

    def __init__(self, session: Any, ctx: RunContext, agent: Agent, actor: Actor) -> None:
        hz = ctx.hz if ctx.realtime else 0.0
        self.agent = agent
        self.runner = Runner(agent, ctx.world, clock=RunControl(speed=hz, default_speed=hz),
                             out=ctx.out, counter=actor.counter, key=actor.controls.key,
                             run_id=ctx.run_id)
        self.display = Display(session, ctx.run_id, placement=ctx.placement or "embedded",
                               world=ctx.world, seed=ctx.seed, actor=actor.name)
        self.clock_name = "realtime" if ctx.realtime else "lockstep"
        self.commands = BoundaryCommands(actor.controls, self.runner, self.publish)
        self.side = trio.CancelScope()
        self.closed = False

    def close(self) -> None:
        if not self.closed:
            self.display.close()
        self.closed = True

    def publish(self, force: bool) -> None:
        self.display.publish(self.agent, self.runner.clock, clock_name=self.clock_name,
                             force=force)

    async def between_steps(self) -> None:
        with self.side:
            await self.commands.between_steps()

    def last(self, steps_done: int) -> None:
        """The run is over: the last commands and the final status."""
        self.side.cancel()                      # no command or status from the side now
        self.commands.at_boundary = False
        self.commands.apply()
        self.runner.finished = True
        self.display.finish()
        if not self.runner.message.startswith("run ended"):
            self.runner.message = f"finished {steps_done} steps"
        self.publish(True)


class Files:
    """The executor's outputs (nothing without ``ctx.out``)."""

    def __init__(self, ctx: RunContext, agent: Agent, resume: Resume) -> None:
        self.ctx, self.agent, self.t_start = ctx, agent, time.perf_counter()
        self.metrics = MetricsLog(Path(ctx.out) / METRICS_FILE, agent, start=resume.step + 1,
                                  every=ctx.metrics_every) if ctx.out is not None else None
        self.rejected = Rejections.from_state(resume.state.get("rejected"))
        """The observations rejected (``step t: why``), a snapshot's ones first."""
        # The last periodic checkpoint: (agent step, agent commands applied by then, its path).
        self.last_saved: tuple[int, int, Path | None] = (-1, -1, None)
        self.writer = CheckpointWriter()
        """Writes the periodic checkpoints off the step chain (docs/decisions.md 81)."""
        self.deferred: tuple[Path, int, int | None] | None = None
        """The run's last step's checkpoint, written by :meth:`flush` (decision 87)."""
        self.closed = False

    def after_step(self, t: int, p: Percept | None, changes: int) -> None:
        """The metrics of step t and, after an accepted step, the periodic checkpoint."""
        ctx, agent = self.ctx, self.agent
        if self.metrics is not None:
            self.metrics.after_step(t + 1, agent)
        if p is not None and ctx.out is not None and (t + 1) % ctx.checkpoint_every == 0:
            root, keep = Path(ctx.out) / "checkpoints", ctx.keep_checkpoints
            if keep != 0 and t + 1 == ctx.end:  # the last step: no copy, see flush
                self.deferred = (root, t + 1, keep)
            else:                               # a deep copy now, written in the writer's thread
                self.writer.save(agent, root, t + 1, ctx.world, keep)
            self.last_saved = (agent.step_count, changes,
                               None if keep == 0 else root / step_name(t + 1))

    def flush(self) -> None:
        """After the run's last step, before anything else (the end's commands) may change
        the agent: that step's checkpoint, written from the agent itself — nothing changes it
        any more, so it needs no copy (docs/decisions.md 87)."""
        if self.deferred is not None:
            root, step, keep = self.deferred
            self.deferred = None
            self.writer.save(self.agent, root, step, self.ctx.world, keep, copy_agent=False)

    def result(self, steps_done: int, quit_at: int | None) -> dict[str, Any]:
        """The executor's part of its result."""
        return {"rejected_observations": self.rejected.count,
                "rejected_examples": list(self.rejected.examples), "wall_s": self.wall(),
                "steps_done": steps_done, **({} if quit_at is None else {"quit_at_step": quit_at})}

    def final(self, steps: int, changes: int) -> None:
        """``knowledge.json``, ``checkpoints/final`` and the executor's summary."""
        ctx, agent = self.ctx, self.agent
        self.writer.wait()
        if ctx.out is None:
            return
        out = Path(ctx.out)
        atomic_write_json(out / "knowledge.json", agent.knowledge())
        # final links to the last step-N when nothing changed the agent since (no step, no
        # goal command): the same state, not a copy.
        same = self.last_saved[2] if self.last_saved[:2] == (agent.step_count, changes) \
            else None
        save_final_checkpoint(agent, out / "checkpoints", ctx.world, same_as=same)
        summary = summary_of(agent, type("W", (), {"name": ctx.world})(), ctx.seed, steps,
                             self.wall(), self.rejected)
        atomic_write_json(out / "actors" / "executor.json", summary)

    def wall(self) -> float:
        return time.perf_counter() - self.t_start

    def close(self, steps: int) -> None:
        """The metrics log ends (once); the checkpoint in flight is written."""
        self.writer.wait()
        if not self.closed and self.metrics is not None:
            self.metrics.finish(steps, self.agent)
        self.closed = True
