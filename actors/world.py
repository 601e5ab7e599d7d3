"""The world actor: steps the physics in lockstep with the executor (docs/architecture.md §1).

Publishes ``sense(t)`` — the world's observation at t plus the motor values being applied
(those of ``motor(t − 1)``) — then waits for ``motor(t)``, applies it and steps. It keeps its
recent ``sense`` messages in a replay log for a perception actor restarted from a snapshot.
The world itself is not restartable (docs/runtime.md); its state goes into the run's
checkpoints (``world.json``, :mod:`.checkpoint_parts`) for an exact ``--resume``.

A value the agent would reject (NaN, ±inf, |x| > ``MAX_ABS_VALUE``) is counted here
(``rejected_senses``) and published in a form the bus can carry — a NaN left out (the agent
reads a missing value as NaN), ±inf as ±``sys.float_info.max`` — so that the perception actor
rejects ``sense(t)`` as the synchronous loop does and every actor skips step t. A world whose
``step`` raises ends the run like a ``quit`` after the last step whose motor was chosen (the
other actors write what was learned), then :class:`~qlap_runtime.agent_run.WorldFailed` is
raised.

It drives the clock, so it obeys the UI's clock commands on ``control`` (docs/runtime.md,
Controls) between two steps: ``pause``, ``resume``, ``step {"n": k}``, ``speed {"steps_per_s":
x}`` (lockstep: pace; realtime: tick rate) and ``quit``, after which it publishes the end
marker ``quit {"last_step": T}`` so that every other actor ends its loop after step T. Pausing
only delays steps, so a lockstep run learns the same whether paused or not.
"""

from __future__ import annotations

import math
import sys
import time

import trio

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import (
    Publisher,
    RejectionCounter,
    TrioSubscriber,
    alive_actors,
    declare_alive,
)
from qlap_runtime.bus.faults import Faults
from qlap_runtime.bus.replay import ReplayLog, fetch_replay
from qlap_runtime.bus.schema import Control, Sense, WorldView
from qlap_runtime.qlap.perception import MAX_ABS_VALUE
from qlap_runtime.runtime.clock import LockstepClock, RealtimeClock
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.controls import Controls
from qlap_runtime.runtime.inbox import StepInbox
from qlap_runtime.runtime.rules import motor_rule
from qlap_runtime.runtime.watchdog import slot_of

from .checkpoint_parts import final_dir, keep_on_stall, part_dir, save_world_part
from .executor import ExecutorActor
from .perception import PerceptionActor
from .resume import applied_motors, restore_world

NAME = "world"
OTHERS_END_S = 120.0
"""How long a failed world waits for the other actors to write their outputs."""


def bus_values(values: dict, available_from: dict[str, int], t: int) -> tuple[dict, bool]:
    """``values`` as ``sense(t)`` can carry them, and whether the agent rejects them (a NaN,
    ±inf or |x| > ``MAX_ABS_VALUE`` of an available variable). A NaN is left out, ±inf becomes
    ±``sys.float_info.max``: the perception actor then sees what the synchronous agent sees."""
    bad = False
    out = values
    for k, v in values.items():
        try:
            if abs(v) <= MAX_ABS_VALUE:     # False on NaN: the fast path of every step
                continue
            fv = float(v)
        except (TypeError, ValueError):
            continue                        # not a number: the perception actor names it
        if out is values:
            out = dict(values)
        if math.isnan(fv):
            del out[k]
            bad = bad or t >= available_from.get(k, 0)
        else:
            if math.isinf(fv):
                out[k] = math.copysign(sys.float_info.max, fv)
            bad = True
    return out, bad


async def run(session, ctx: RunContext, ready: trio.Event | None = None,
              perception: PerceptionActor | None = None,
              executor: ExecutorActor | None = None) -> dict:
    """The world actor's loop. In the embedded placement it hosts the rest of the step chain:
    right after publishing ``sense(t)`` it runs the perception actor's step (``perception``),
    then the executor's (``executor``), whose ``motor(t)`` is then already in its inbox; after
    the last step it ends them (their replay logs kept open for the learners behind)."""
    import worlds

    world = worlds.make(ctx.world)
    counter = RejectionCounter(NAME)
    slot = slot_of(ctx, NAME)
    stats = {"steps": 0, "wait_s": 0.0}
    try:
        motors = [v.name for v in world.variables if getattr(v.kind, "value", v.kind) == "motor"]
        applied = dict.fromkeys(motors, 0.0)
        available = {v.name: int(getattr(v, "available_from", 0) or 0)
                     for v in world.variables}
        failed = None
        if ctx.resume_checkpoint is not None:  # a resumed run: the checkpoint's state
            obs = restore_world(world, ctx.resume_checkpoint)
            applied.update(applied_motors(ctx.resume_checkpoint))
        else:
            obs = world.reset(seed=ctx.seed)
        with declare_alive(session, ctx.run_id, NAME), \
                TrioSubscriber(session, keys.key(ctx.run_id, "motor"), counter=counter) as sub, \
                Publisher(session, ctx.run_id, "sense", faults=Faults.of(ctx.faults),
                          tag=NAME) as pub, \
                Publisher(session, ctx.run_id, "world") as view, \
                ReplayLog(session, ctx.run_id, "sense", ctx.replay_keep) as replay, \
                Controls(session, ctx, counter) as controls, \
                Publisher(session, ctx.run_id, "control") as end_marker:
            start = ctx.start
            # A motor for a step the world has not sensed yet cannot be the executor's: the
            # lockstep window is 0 (docs/runtime.md, "Rules on messages").
            # A motor that does not come in time is asked for again from the executor's
            # replay log (a lost message; a restarted executor).
            inbox = StepInbox(sub, first=start, slot=slot, topic="motor", counter=counter,
                              key=keys.key(ctx.run_id, "motor"),
                              refill=None if ctx.realtime else _motor_refill(session, ctx,
                                                                             counter),
                              window=None if ctx.realtime else 0,
                              rule=motor_rule(world.variables))
            last_view = 0.0
            for hosted in (perception, executor):
                if hosted is not None:
                    await hosted.start()        # alive: the launcher waits for its token
            if ready is not None:
                await ready.wait()
            clock = RealtimeClock(controls, counter, slot, ctx.hz) if ctx.realtime \
                else LockstepClock(controls, counter, slot)
            clock.start(start)
            last = start - 1
            loop_t0 = time.perf_counter()
            for t in range(start, start + ctx.steps):
                if not await clock.before(t):
                    break
                values = dict(obs)
                values.update(applied)
                values, bad = bus_values(values, available, t)
                if bad:
                    stats["rejected_senses"] = stats.get("rejected_senses", 0) + 1
                sense = Sense(t, values, bool(getattr(world, "discontinuity", False)))
                if pub.put(sense) or not (pub.faults and pub.faults.lost):
                    replay.append(t, sense)         # for a perception actor restarted later
                # This session hands each message to the next actor's inbox during put, so
                # the hosted steps take it without a wait or a wake-up.
                if perception is not None:
                    await perception.step(t)
                if executor is not None:
                    await executor.step(t)
                    # A hosted step chain need not wait for anything: yield once a step, so
                    # that the other tasks (learners, controls, viewers) keep running.
                    await trio.lowlevel.checkpoint()
                t0 = time.perf_counter()
                motor = await clock.motor(inbox, t)
                stats["wait_s"] += time.perf_counter() - t0
                if motor is not None:
                    applied = dict(motor.values)
                try:
                    obs = world.step(applied)
                except Exception as exc:    # end the run after t (its motor was chosen)
                    from qlap_runtime.errors import WorldFailed

                    failed = WorldFailed(ctx.world, t, exc)
                    stats["world_error"] = str(failed)
                    stats["steps"] += 1
                    last = t
                    clock.state.quit = True
                    break
                now = time.perf_counter()
                if now - last_view >= 0.1:                    # the UI's world panel, 10 Hz
                    last_view = now
                    view.put(WorldView(t, str(getattr(world, "name", ctx.world)),
                                       world.render_text(44, 14),
                                       {k: float(v) for k, v in obs.items()
                                        if math.isfinite(v)}, applied, {}))
                stats["steps"] += 1
                clock.stepped()
                slot.done(t)
                last = t
                save_world_part(part_dir(ctx, t), world)   # the executor's checkpoint's part
            slot.finished()
            if failed is None:
                save_world_part(final_dir(ctx), world)
            if clock.state.quit:
                # The end marker: every other actor ends after step `last` (the last one whose
                # sense was published and whose motor was applied) and writes its outputs.
                end_marker.put(Control("quit", {"last_step": last}))
                stats["quit_at_step"] = last
            # The step chain's own rate, start-up (imports, sessions, waiting for the other
            # actors) and pauses excluded: what the benchmarks compare between placements.
            stats["loop_s"] = round(time.perf_counter() - loop_t0 - clock.paused_s, 3)
            stats["paused_s"] = round(clock.paused_s, 3)
            if executor is not None:
                await executor.finish(last if clock.state.quit else None)
            if perception is not None:
                await perception.finish()
    except BaseException:                       # cancelled (maybe in a group) by a stall
        keep_on_stall(ctx, world=world)         # a stalled run keeps the world's state
        raise
    finally:
        world.close()
    stats["rejected"] = counter.snapshot().total
    if inbox.refills:
        stats["refills"] = inbox.refills
    if pub.faults is not None:
        stats["injected"] = pub.faults.counts()
    if failed is not None:
        await _after_failure(session, ctx, stats)
        raise failed
    stats.update(clock.stats())
    return stats



def _motor_refill(session, ctx: RunContext, counter: RejectionCounter):
    async def refill(step: int) -> list:
        return await fetch_replay(session, ctx.run_id, "motor", step, counter=counter)
    return refill


async def _after_failure(session, ctx: RunContext, stats: dict) -> None:
    """The world failed and published the end marker: wait for the other actors to end (their
    outputs written), then add the failure to the run's summary.json."""
    with trio.move_on_after(OTHERS_END_S):
        # Polled (a subscription's history can miss a token that goes while it answers).
        while (await alive_actors(session, ctx.run_id)) - {NAME}:  # noqa: ASYNC110
            await trio.sleep(0.05)
    if ctx.out is None:
        return
    import json
    from pathlib import Path

    from qlap_runtime.qlap.checkpoint import atomic_write_json

    out = Path(ctx.out)
    executor = out / "actors" / "executor.json"
    try:
        summary = json.loads(executor.read_text()) if executor.exists() else {}
    except (OSError, ValueError):
        summary = {}
    summary.update(placement=ctx.placement, world=ctx.world, seed=ctx.seed,
                   steps=stats["steps"], world_error=stats["world_error"], world_actor=stats)
    atomic_write_json(out / "summary.json", summary)
