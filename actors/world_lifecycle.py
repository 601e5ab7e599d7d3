"""The world actor's life around its step (:mod:`actors.world`): the hosted actors' starts,
the wait for the launcher's go, the loop on the world's clock, then the end — the final world
part, the end marker after a ``quit``, the hosted actors' ends, and a failed world's summary
once the others wrote their outputs. A base class of :class:`~actors.world.WorldActor`, kept
apart so that the actor's module reads receive -> algorithm -> publish."""

from __future__ import annotations

from typing import Any

import trio

from qlap_runtime.bus.bridge import Publisher
from qlap_runtime.bus.schema import Control
from qlap_runtime.errors import WorldFailed
from qlap_runtime.runtime.actor import Actor, ActorBase
from qlap_runtime.runtime.clock import LockstepClock, RealtimeClock
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.outputs import write_failure_summary

from .checkpoint_parts import final_dir, save_world_part
from .convert import SenseCodec

OTHERS_END_S = 120.0
"""How long a failed world waits for the other actors to write their outputs."""


class WorldLifecycle(ActorBase):
    """The world's :meth:`run` (the fields and :meth:`step` are the world actor's)."""

    ctx: RunContext
    actor: Actor
    world: Any
    clock: LockstepClock | RealtimeClock
    stats: dict[str, Any]
    senses: SenseCodec
    end_marker: Publisher
    perception: ActorBase | None
    executor: Any
    failure: WorldFailed | None

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
        for t in range(ctx.start, ctx.end):
            if not await self.step(t):
                break
        last = ctx.start - 1 + stats["steps"]   # the last step sensed and its motor applied
        stats.update(clock.stop())
        if self.senses.rejected:
            stats["rejected_senses"] = self.senses.rejected
        self.actor.slot.finished()
        if self.failure is None:
            save_world_part(final_dir(ctx), self.world)
        if clock.state.quit:                    # every other actor ends after step `last`
            self.end_marker.put(Control("quit", {"last_step": last}))
            stats["quit_at_step"] = last
        if self.executor is not None:
            await self.executor.finish(last if clock.state.quit else None)
        if self.perception is not None:
            await self.perception.finish()
        self.result = self.actor.result(**stats, **clock.stats())
        if self.failure is not None:            # once the others wrote their outputs
            await self.actor.others_ended(OTHERS_END_S)
            write_failure_summary(ctx, self.result)
            raise self.failure
        return self.result
