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
from qlap_runtime.bus.schema import CallList, Motor
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import atomic_write_json, save_agent

from .common import DeltaInbox, RunContext, StepInbox, percept_from_qstate, world_variables

NAME = "executor"


async def run(session, ctx: RunContext) -> dict:
    specs, _ = world_variables(ctx.world)
    agent = Agent(specs, ctx.params, seed=ctx.seed)
    agent.learner.auto_batches = False
    agent.learner.follower = True
    counter = RejectionCounter(NAME)
    rejected: list[str] = []
    t_start = time.perf_counter()
    with declare_alive(session, ctx.run_id, NAME), \
            TrioSubscriber(session, keys.key(ctx.run_id, "qstate"), counter=counter) as sub, \
            Publisher(session, ctx.run_id, "motor") as pub, \
            Publisher(session, ctx.run_id, "calllist") as calls_pub:
        deltas = DeltaInbox(session, ctx, counter)
        try:
            inbox = StepInbox(sub)
            start = ctx.extra.get("start_step", 0)
            for t in range(start, start + ctx.steps):
                msg = await inbox.get(t)
                if msg.rejected:
                    deltas.book.skipped.add(t)
                    rejected.append(f"step {t}: {msg.rejected}")
                    pub.put(Motor(t, dict(agent.motor)))
                    continue
                p = percept_from_qstate(msg, agent.table)
                agent.learner.observe_percept(p)
                for d in await deltas.due(t):
                    agent.learner.apply_delta(d)
                motor = agent.decide(p)
                pub.put(Motor(t, motor))
                if t % 50 == 0:
                    calls_pub.put(CallList(t, tuple(agent.call_list_labels())))
                if ctx.out is not None and (t + 1) % ctx.checkpoint_every == 0:
                    save_agent(agent, Path(ctx.out) / "checkpoints" / f"step-{t + 1:07d}")
        finally:
            deltas.close()
    wall = time.perf_counter() - t_start
    result = {"rejected": counter.snapshot().total, "waits": deltas.book.waits,
              "wait_s": round(deltas.wait_s, 3), "rejected_observations": len(rejected),
              "rejected_examples": rejected[:20], "wall_s": wall}
    if ctx.out is not None:
        out = Path(ctx.out)
        atomic_write_json(out / "knowledge.json", agent.knowledge())
        save_agent(agent, out / "checkpoints" / "final")
        from qlap_runtime.agent_run import summary_of

        summary = summary_of(agent, type("W", (), {"name": ctx.world})(), ctx.seed, ctx.steps,
                             wall, rejected)
        atomic_write_json(out / "actors" / f"{NAME}.json", summary)
    return result
