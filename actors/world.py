"""The world actor: steps the physics in lockstep with the executor (docs/architecture.md §1).

Publishes ``sense(t)`` — the observation at t plus the motor values being applied (those of
``motor(t − 1)``) — then waits for ``motor(t)``, applies it and steps; its clock
(:mod:`qlap_runtime.runtime.clock`) obeys the UI's clock commands between two steps, and after
a ``quit`` it publishes the end marker ``quit {"last_step": T}`` (docs/runtime.md, Controls). A
value the agent would reject is counted (``rejected_senses``) and sent so that every actor
skips step t (:func:`~actors.convert.sense_values`). The world is not restartable; its state
goes into the run's checkpoints (``world.json``). A world whose ``step`` raises ends the run
like a ``quit`` after its last step, then :class:`~qlap_runtime.errors.WorldFailed` is raised.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import trio

from qlap_runtime.bus.schema import Control, Sense
from qlap_runtime.errors import WorldFailed
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.clock import LockstepClock, RealtimeClock
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.outputs import write_failure_summary
from qlap_runtime.runtime.rules import motor_rule

from .checkpoint_parts import final_dir, keep_on_stall, part_dir, save_world_part
from .convert import sense_values, world_view
from .resume import applied_motors, restore_world

NAME = "world"
OTHERS_END_S = 120.0
"""How long a failed world waits for the other actors to write their outputs."""
VIEW_S = 0.1
"""The UI's world panel is published at most this often."""


class WorldActor(ActorBase):
    """The world, its clock and its topics. In the embedded placement it hosts the rest of the
    step chain: ``perception``'s step, then ``executor``'s, right after ``sense(t)``, their
    inputs already in their inboxes (docs/decisions.md 52)."""

    def __init__(self, session: Any, ctx: RunContext, world: Any,
                 perception: ActorBase | None = None, executor: Any = None) -> None:
        self.ctx, self.world, self.perception, self.executor = ctx, world, perception, executor
        self.actor = actor = Actor(session, ctx, NAME, obey=True)
        self.applied = {v.name: 0.0 for v in world.variables
                        if getattr(v.kind, "value", v.kind) == "motor"}
        self.available = {v.name: int(getattr(v, "available_from", 0) or 0)
                          for v in world.variables}
        if ctx.resume_checkpoint is not None:  # a resumed run: the checkpoint's state
            self.obs = restore_world(world, ctx.resume_checkpoint)
            self.applied.update(applied_motors(ctx.resume_checkpoint))
        else:
            self.obs = world.reset(seed=ctx.seed)
        # A motor for a step not sensed yet cannot be the executor's (lockstep window 0).
        self.motors = actor.input("motor", window=0, rule=motor_rule(world.variables), end=False)
        self.sense = actor.output("sense")
        self.view, self.end_marker = actor.publisher("world"), actor.publisher("control")
        self.clock = RealtimeClock(actor.controls, actor.counter, actor.slot, ctx.hz) \
            if ctx.realtime else LockstepClock(actor.controls, actor.counter, actor.slot)
        self.stats: dict[str, Any] = {"steps": 0, "wait_s": 0.0}
        self.failure: WorldFailed | None = None
        self.last_view = 0.0

    async def step(self, t: int) -> bool:
        """``sense(t)``, the hosted steps, ``motor(t)``, the physics; False: the run ends."""
        if not await self.clock.before(t):
            return False
        values, bad = sense_values({**self.obs, **self.applied}, self.available, t)
        if bad:
            self.stats["rejected_senses"] = self.stats.get("rejected_senses", 0) + 1
        self.sense.put(t, Sense(t, values, bool(getattr(self.world, "discontinuity", False))))
        if self.perception is not None:
            await self.perception.step(t)
        if self.executor is not None:
            await self.executor.step(t)
            await trio.lowlevel.checkpoint()    # yield once a step: learners, controls, viewers
        t0 = time.perf_counter()
        motor = await self.clock.motor(self.motors, t)
        self.stats["wait_s"] += time.perf_counter() - t0
        if motor is not None:
            self.applied = dict(motor.values)
        self.stats["steps"] += 1
        try:
            self.obs = self.world.step(self.applied)
        except Exception as exc:                # end the run after t (its motor was chosen)
            self.failure = WorldFailed(self.ctx.world, t, exc)
            self.stats["world_error"] = str(self.failure)
            self.clock.state.quit = True
            return False
        if (now := time.perf_counter()) - self.last_view >= VIEW_S:
            self.last_view = now
            self.view.put(world_view(self.world, self.ctx.world, t, self.obs, self.applied))
        self.clock.stepped()
        self.actor.slot.done(t)
        save_world_part(part_dir(self.ctx, t), self.world)    # the executor's checkpoint's
        return True

    async def run(self, ready: trio.Event | None = None) -> dict[str, Any]:  # type: ignore[override]
        """The loop; then the end marker (after a quit) and the hosted actors' ends."""
        ctx, clock, stats = self.ctx, self.clock, self.stats
        await self.actor.start()
        for hosted in (self.perception, self.executor):
            if hosted is not None:
                await hosted.start()            # alive: the launcher waits for its token
        if ready is not None:
            await ready.wait()
        clock.start(ctx.start)
        loop_t0 = time.perf_counter()
        for t in range(ctx.start, ctx.end):
            if not await self.step(t):
                break
        last = ctx.start - 1 + stats["steps"]   # the last step sensed and its motor applied
        self.actor.slot.finished()
        if self.failure is None:
            save_world_part(final_dir(ctx), self.world)
        if clock.state.quit:                    # every other actor ends after step `last`
            self.end_marker.put(Control("quit", {"last_step": last}))
            stats["quit_at_step"] = last
        # The step chain's own rate, start-up and pauses excluded (the benchmarks' figure).
        stats["loop_s"] = round(time.perf_counter() - loop_t0 - clock.paused_s, 3)
        stats["paused_s"] = round(clock.paused_s, 3)
        if self.executor is not None:
            await self.executor.finish(last if clock.state.quit else None)
        if self.perception is not None:
            await self.perception.finish()
        return self.actor.result(**stats, **({} if self.failure else clock.stats()))

    async def failed(self, result: dict[str, Any]) -> None:
        """After a failure (the end marker published): once the other actors have ended, their
        outputs written, the failure goes into the run's summary."""
        ctx = self.ctx
        await self.actor.others_ended(OTHERS_END_S)
        if ctx.out is not None:
            write_failure_summary(Path(ctx.out), placement=ctx.placement, world=ctx.world,
                                  seed=ctx.seed, steps=result["steps"],
                                  world_error=result["world_error"], world_actor=result)


async def run(session: Any, ctx: RunContext, ready: trio.Event | None = None,
              perception: ActorBase | None = None, executor: Any = None) -> dict[str, Any]:
    """The world actor's task; in the embedded placement it hosts ``perception`` and
    ``executor`` (the step chain in one task)."""
    import worlds

    world = worlds.make(ctx.world)
    try:
        with WorldActor(session, ctx, world, perception, executor) as me:
            result = await me.run(ready)
    except BaseException:                       # cancelled (maybe in a group) by a stall
        keep_on_stall(ctx, world=world)         # a stalled run keeps the world's state
        raise
    finally:
        world.close()
    if me.failure is not None:
        await me.failed(result)
        raise me.failure
    return result
