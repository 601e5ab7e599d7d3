"""The world actor: steps the physics in lockstep with the executor (DESIGN.md §3.3).

Publishes ``sense(t)`` — the world's observation at t plus the motor values being applied
(those of ``motor(t − 1)``) — then waits for ``motor(t)``, applies it and steps.
"""

from __future__ import annotations

import time

import trio

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.schema import Sense, WorldView

from .common import RunContext, StepInbox

NAME = "world"


async def run(session, ctx: RunContext, ready: trio.Event | None = None) -> dict:
    import worlds

    world = worlds.make(ctx.world)
    counter = RejectionCounter(NAME)
    stats = {"steps": 0, "wait_s": 0.0}
    try:
        motors = [v.name for v in world.variables if getattr(v.kind, "value", v.kind) == "motor"]
        applied = dict.fromkeys(motors, 0.0)
        obs = world.reset(seed=ctx.seed)
        with declare_alive(session, ctx.run_id, NAME), \
                TrioSubscriber(session, keys.key(ctx.run_id, "motor"), counter=counter) as sub, \
                Publisher(session, ctx.run_id, "sense") as pub, \
                Publisher(session, ctx.run_id, "world") as view:
            inbox = StepInbox(sub)
            last_view = 0.0
            if ready is not None:
                await ready.wait()
            start = ctx.extra.get("start_step", 0)
            for t in range(start, start + ctx.steps):
                values = dict(obs)
                values.update(applied)
                pub.put(Sense(t, values))
                t0 = time.perf_counter()
                motor = await inbox.get(t)
                stats["wait_s"] += time.perf_counter() - t0
                applied = dict(motor.values)
                obs = world.step(applied)
                now = time.perf_counter()
                if now - last_view >= 0.1:                    # the UI's world panel, 10 Hz
                    last_view = now
                    view.put(WorldView(t, str(getattr(world, "name", ctx.world)),
                                       world.render_text(44, 14),
                                       {k: float(v) for k, v in obs.items()}, applied, {}))
                stats["steps"] += 1
    finally:
        world.close()
    stats["rejected"] = counter.snapshot().total
    return stats
