"""The executor actor: plans, the call list, IAC and babbling (ch. 5–6) -> ``motor(t)``.

It holds the :class:`~qlap_runtime.qlap.agent.Agent` whose learner is a follower: it keeps the
DBN statistics that rel(r, s) needs from the ``qstate`` stream and applies the batch actors'
deltas at step boundaries, but never learns DBNs or landmarks itself. Plan conversion (Algorithm
2 line 15) runs here, right after the deltas are applied, because it reads the executor's own
action and plan statistics (a departure from a separate planner actor, see docs/runtime.md).
Writes checkpoints, ``knowledge.json`` and ``summary.json`` like the synchronous loop.
"""

from __future__ import annotations

import time
from pathlib import Path

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.replay import ReplayLog
from qlap_runtime.bus.schema import Motor
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import atomic_write_json, load_agent, save_agent

from .common import (
    DeltaInbox,
    Resume,
    RunContext,
    StepInbox,
    percept_from_qstate,
    resume_inputs,
    snapshot_due,
    snapshot_stats,
    world_variables,
    write_snapshot,
)

NAME = "executor"


async def run(session, ctx: RunContext) -> dict:
    specs, _ = world_variables(ctx.world)
    resume = Resume.of(ctx, NAME)
    agent = load_agent(resume.path) if resume.path is not None \
        else Agent(specs, ctx.params, seed=ctx.seed)
    agent.learner.auto_batches = False
    agent.learner.follower = True
    counter = RejectionCounter(NAME)
    rejected: list[str] = list(resume.state.get("rejected", []))
    snapshot_s: list[float] = []
    t_start = time.perf_counter()
    with declare_alive(session, ctx.run_id, NAME), \
            TrioSubscriber(session, keys.key(ctx.run_id, "qstate"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, "motor") as pub, \
            ReplayLog(session, ctx.run_id, "motor", ctx.replay_keep) as replay, \
            Display(session, ctx) as display:
        deltas = DeltaInbox(session, ctx, counter)
        try:
            inbox = StepInbox(sub, first=resume.step + 1)
            await resume_inputs(session, ctx, resume, inbox, "qstate", deltas, counter)
            for t in range(resume.step + 1, ctx.start + ctx.steps):
                msg = await inbox.get(t)
                if msg.rejected:
                    deltas.book.skipped.add(t)
                    rejected.append(f"step {t}: {msg.rejected}")
                    motor = Motor(t, dict(agent.motor))
                else:
                    p = percept_from_qstate(msg, agent.table)
                    agent.learner.observe_percept(p)
                    for d in await deltas.due_now(t, ctx.realtime):
                        agent.learner.apply_delta(d)
                    motor = Motor(t, dict(agent.decide(p)))
                pub.put(motor)
                replay.append(t, motor)
                if not msg.rejected:
                    display.publish(agent, deltas)
                    if ctx.out is not None and (t + 1) % ctx.checkpoint_every == 0:
                        save_agent(agent, Path(ctx.out) / "checkpoints" / f"step-{t + 1:07d}")
                if snapshot_due(ctx, t):
                    snapshot_s.append(write_snapshot(ctx, NAME, t, deltas,
                                                     lambda d: save_agent(agent, d),
                                                     rejected=rejected))
        finally:
            deltas.close()
    wall = time.perf_counter() - t_start
    result = {"rejected": counter.snapshot().total, "waits": deltas.book.waits,
              "wait_s": round(deltas.wait_s, 3), "rejected_observations": len(rejected),
              "rejected_examples": rejected[:20], "wall_s": wall,
              **snapshot_stats(snapshot_s, resume)}
    if ctx.out is not None:
        out = Path(ctx.out)
        atomic_write_json(out / "knowledge.json", agent.knowledge())
        save_agent(agent, out / "checkpoints" / "final")
        from qlap_runtime.agent_run import summary_of

        summary = summary_of(agent, type("W", (), {"name": ctx.world})(), ctx.seed, ctx.steps,
                             wall, rejected)
        atomic_write_json(out / "actors" / f"{NAME}.json", summary)
    return result


class Display:
    """The display topics the terminal UI reads (docs/tui.md), published with DROP at a bounded
    rate: they only read the agent, so they never change what it does."""

    def __init__(self, session, ctx: RunContext) -> None:
        from qlap_runtime import telemetry

        self.telemetry = telemetry
        self.ctx = ctx
        self.cadence = telemetry.Cadence()
        self.t0 = time.perf_counter()
        self.pubs = {topic: Publisher(session, ctx.run_id, topic)
                     for topic in ("iac", "calllist", "status", "stats", "knowledge")}

    def publish(self, agent: Agent, deltas: DeltaInbox) -> None:
        tm, cad, now = self.telemetry, self.cadence, time.perf_counter()
        if cad.display_due(now):
            for msg in tm.iac_msgs(agent, cad.last_iac_step):
                self.pubs["iac"].put(msg)
                cad.last_iac_step = msg.step
            self.pubs["calllist"].put(tm.call_list_msg(agent))
            status = tm.status_msg(
                agent, steps_per_s=cad.steps_per_s(now, agent.step_count), paused=False,
                clock="lockstep", placement=self.ctx.extra.get("placement", "embedded"),
                world=self.ctx.world, seed=self.ctx.seed, wall_s=now - self.t0)
            self.pubs["status"].put(status)
            if cad.stats_due(now):
                self.pubs["stats"].put(tm.stats_msg(status, actor=NAME))
        sig = tm.knowledge_signature(agent)
        if cad.knowledge_due(now, agent.step_count, sig):
            cad.last_signature = sig
            self.pubs["knowledge"].put(tm.knowledge_msg(agent))

    def __enter__(self) -> Display:
        return self

    def __exit__(self, *exc: object) -> None:
        for pub in self.pubs.values():
            pub.close()
