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

from qlap_runtime.bus.schema import Motor, encode
from qlap_runtime.metrics import METRICS_FILE, MetricsLog, summary_of
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import (
    atomic_write_json,
    load_agent,
    save_agent,
    save_final_checkpoint,
    save_step_checkpoint,
)
from qlap_runtime.runtime.actor import Actor
from qlap_runtime.runtime.context import RunContext, world_variables
from qlap_runtime.runtime.controls import RunControl
from qlap_runtime.runtime.lockstep import batch_kinds
from qlap_runtime.runtime.rules import qstate_rule
from qlap_runtime.runtime.runner import BoundaryCommands, Display, Runner

from .checkpoint_parts import gather_final_parts, keep_on_stall
from .convert import QStateCodec, batch_context
from .resume import checkpoint_of

NAME = "executor"


async def run(session: Any, ctx: RunContext) -> dict[str, Any]:
    specs, _ = world_variables(ctx.world)
    t_start = time.perf_counter()
    steps_done = 0
    with Actor(session, ctx, NAME, obey=True) as actor:
        resume = actor.resume
        checkpoint = checkpoint_of(ctx, resume.path)
        agent = load_agent(resume.path) if resume.path is not None \
            else load_agent(checkpoint) if checkpoint is not None \
            else Agent(specs, ctx.params, seed=ctx.seed)
        agent.learner.pending_deltas.clear()    # a resumed run's: refused before the run
        agent.learner.auto_batches = False
        agent.learner.follower = True
        rejected: list[str] = list(resume.state.get("rejected", []))
        metrics = MetricsLog(Path(ctx.out) / METRICS_FILE, agent, start=resume.step + 1,
                             every=ctx.metrics_every) if ctx.out is not None else None
        # The last periodic checkpoint: (agent step, agent commands applied by then, its path).
        last_saved: tuple[int, int, Path | None] = (-1, -1, None)
        codec = QStateCodec(agent.table)
        actor.input("qstate", window=1, rule=qstate_rule(codec.names))
        deltas = actor.deltas(len(agent.table))
        motors, contexts = actor.output("motor"), actor.output("batchctx")
        # batchctx(s) of a batch at s + 1 went out before the snapshot at s, so a restarted
        # executor never publishes it again: its snapshot carries the logged ones, served
        # again to a batch actor restarted later from an older snapshot (docs/runtime.md).
        actor.restore_log(contexts, resume.state.get("batchctx", []))
        hz = ctx.hz if ctx.realtime else 0.0
        runner = Runner(agent, ctx.world, clock=RunControl(speed=hz, default_speed=hz),
                        out=ctx.out, counter=actor.counter, key=actor.controls.key,
                        run_id=ctx.run_id)
        display = Display(session, ctx.run_id, placement=ctx.placement or "embedded",
                          world=ctx.world, seed=ctx.seed, actor=NAME)
        clock_name = "realtime" if ctx.realtime else "lockstep"

        def publish(force: bool) -> None:
            display.publish(agent, runner.clock, clock_name=clock_name, force=force)

        commands = BoundaryCommands(actor.controls, runner, publish)
        try:
            await actor.start()
            if checkpoint is not None and batch_kinds(ctx.params, ctx.start) \
                    and ctx.start < ctx.end:
                # A resumed run starting on a batch step: the batch reads the checkpoint's
                # agent (the uninterrupted run's executor published it before motor(N - 1)).
                contexts.put(ctx.start - 1, batch_context(agent, ctx.start - 1))
            async with trio.open_nursery() as nursery:
                nursery.start_soon(commands.between_steps)
                for t in actor.steps():
                    commands.apply()
                    with commands.waiting():
                        msg = await actor.receive(t)
                    if msg is None:
                        break
                    if msg.rejected:
                        deltas.book.skipped.add(t)
                        rejected.append(f"step {t}: {msg.rejected}")
                        motor = Motor(t, dict(agent.motor))
                    else:
                        # The learner's percept (not the message's): a landmark applied at
                        # this step renumbers its q in place, as in the synchronous loop, so
                        # the decision reads the current values with the new landmarks.
                        # Waited for before observing: a cancel (a stall) leaves the agent at
                        # a step boundary, which keep_on_stall saves.
                        due = await deltas.due_now(t, ctx.realtime)
                        p = agent.learner.observe_percept(codec.percept(msg))
                        for d in due:
                            agent.learner.apply_delta(d)
                        motor = Motor(t, dict(agent.decide(p)))
                    if batch_kinds(ctx.params, t + 1) and t + 1 < ctx.end:
                        # Before motor(t): the batch at t + 1 reads this state (§6.2.1).
                        contexts.put(t, batch_context(agent, t))
                    motors.put(t, motor)
                    actor.slot.done(t)
                    steps_done += 1
                    if metrics is not None:
                        metrics.after_step(t + 1, agent)
                    if not msg.rejected:
                        publish(False)
                        if ctx.out is not None and (t + 1) % ctx.checkpoint_every == 0:
                            last_saved = (agent.step_count, runner.agent_changes,
                                          save_step_checkpoint(
                                              agent, Path(ctx.out) / "checkpoints", t + 1,
                                              ctx.world, ctx.keep_checkpoints))
                    if actor.snapshot_due(t):
                        actor.snapshot(t, lambda d: save_agent(agent, d), rejected=rejected,
                                       batchctx=[[s, encode(m).decode()]
                                                 for s, m in contexts.log.entries()])
                nursery.cancel_scope.cancel()
            actor.slot.finished()
            commands.apply()
            runner.finished = True
            display.finish()
            if not runner.message.startswith("run ended"):
                runner.message = f"finished {steps_done} steps"
            publish(True)
        except BaseException:                   # cancelled (maybe in a group) by a stall
            keep_on_stall(ctx, agent)           # a stalled run keeps what was learned
            raise
        finally:
            display.close()
            if metrics is not None:
                metrics.finish(resume.step + 1 + steps_done, agent)
        wall = time.perf_counter() - t_start
        quit_at = actor.controls.last_step
        result = actor.result(wait_s=round(deltas.wait_s, 3), rejected_observations=len(rejected),
                              rejected_examples=rejected[:20], wall_s=wall, steps_done=steps_done,
                              **({} if quit_at is None else {"quit_at_step": quit_at}))
        if ctx.out is not None:
            out = Path(ctx.out)
            atomic_write_json(out / "knowledge.json", agent.knowledge())
            # final links to the last step-N when nothing changed the agent since (no step, no
            # goal command): the same state, not a copy.
            same = last_saved[2] if last_saved[:2] == (agent.step_count,
                                                       runner.agent_changes) else None
            save_final_checkpoint(agent, out / "checkpoints", ctx.world, same_as=same)
            summary = summary_of(agent, type("W", (), {"name": ctx.world})(), ctx.seed,
                                 steps_done if quit_at is not None else ctx.steps, wall, rejected)
            atomic_write_json(out / "actors" / f"{NAME}.json", summary)
        # Outputs first (a failed world waits for the other actors' tokens, then reads
        # them); then a batch actor behind may still ask for a lost batch context.
        await actor.linger(("contingency", "landmarks"))
        if ctx.placement == "distributed":      # no launcher: the executor places them
            await gather_final_parts(session, ctx)
    return result
