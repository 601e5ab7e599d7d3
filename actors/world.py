"""The world actor: publishes ``sense(t)`` (the observation at t and the motors applied, those
of ``motor(t − 1)``), waits for ``motor(t)``, applies it and steps (docs/architecture.md §1).

Its clock (:mod:`qlap_runtime.runtime.clock`) obeys the clock commands between two steps; after
a ``quit`` it publishes the end marker ``quit {"last_step": T}`` (docs/runtime.md, Controls). A
value the agent would reject is counted and sent so that every actor skips step t
(:class:`~actors.convert.SenseCodec`). Not restartable; its state goes into the checkpoints.
A world whose ``step`` raises ends the run like a ``quit``, then ``WorldFailed`` is raised.
"""

from __future__ import annotations

import time
from typing import Any

import trio

from qlap_runtime.errors import WorldFailed
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.clock import world_clock
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.rules import motor_rule

from .chain import Chain
from .checkpoint_parts import keep_on_stall, part_dir, save_world_part
from .convert import SenseCodec, world_view
from .resume import start_world
from .world_lifecycle import WorldLifecycle

NAME = "world"
VIEW_S = 0.1
"""The UI's world panel is published at most this often."""


class WorldActor(WorldLifecycle):
    """The world, its clock and its topics. With ``chain`` it hosts the rest of the step
    chain: ``perception``'s step, then ``executor``'s, right after ``sense(t)``, the values
    passing in memory (:class:`~actors.chain.Chain`, docs/decisions.md 52, 84). Its loop,
    start and end: :class:`~actors.world_lifecycle.WorldLifecycle`."""

    def __init__(self, session: Any, ctx: RunContext, world: Any,
                 perception: ActorBase | None = None, executor: Any = None,
                 chain: Chain | None = None) -> None:
        self.ctx, self.world, self.perception, self.executor = ctx, world, perception, executor
        self.chain = chain
        self.actor = actor = Actor(session, ctx, NAME, obey=True)
        self.obs, self.applied = start_world(world, ctx)
        self.senses = SenseCodec(world.variables)
        # A motor for a step not sensed yet cannot be the executor's (lockstep window 0).
        self.motors = actor.input("motor", window=0, rule=motor_rule(world.variables), end=False,
                                  hosted=chain is not None)
        self.sense = actor.output("sense", logged=chain is None)
        self.view, self.end_marker = actor.publisher("world"), actor.publisher("control")
        self.clock = world_clock(ctx.realtime, ctx.hz, actor.controls, actor.counter, actor.slot)
        self.stats: dict[str, Any] = {"steps": 0}
        self.failure: WorldFailed | None = None
        self.last_view = 0.0

    async def step(self, t: int) -> bool:
        """``sense(t)``, the hosted steps, ``motor(t)``, the physics; False: the run ends."""
        if not await self.clock.before(t):
            return False
        discontinuity = bool(getattr(self.world, "discontinuity", False))
        sense = self.senses.message(t, self.obs, self.applied, discontinuity)
        self.sense.put(t, sense)
        if (chain := self.chain) is None:
            motor = await self.clock.motor(self.motors, t)
        else:
            motor = await chain.step(t, sense, self.perception, self.executor)
            self.motors.discard(t)              # the rules on anything else that came
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


async def run(session: Any, ctx: RunContext, ready: trio.Event | None = None,
              perception: ActorBase | None = None, executor: Any = None,
              chain: Chain | None = None) -> dict[str, Any]:
    """The world actor's task; with ``chain`` it hosts ``perception`` and ``executor`` (the
    step chain in one task)."""
    import worlds

    world = worlds.make(ctx.world)
    try:
        with WorldActor(session, ctx, world, perception, executor, chain) as me:
            return await me.run(ready)
    except WorldFailed:
        raise
    except BaseException:                       # cancelled (maybe in a group) by a stall
        keep_on_stall(ctx, world=world)         # a stalled run keeps the world's state
        raise
    finally:
        world.close()
