"""The world actor: steps the physics in lockstep with the executor (docs/architecture.md §1).

Publishes ``sense(t)`` — the world's observation at t plus the motor values being applied
(those of ``motor(t − 1)``) — then waits for ``motor(t)``, applies it and steps. It keeps its
recent ``sense`` messages in a replay log for a perception actor restarted from a snapshot.
The world itself is not restartable: its physics state is not snapshotted (docs/runtime.md).

It drives the clock, so it obeys the UI's clock commands on ``control`` (docs/runtime.md,
Controls) between two steps: ``pause``, ``resume``, ``step {"n": k}``, ``speed {"steps_per_s":
x}`` (lockstep: pace; realtime: tick rate) and ``quit``, after which it publishes the end
marker ``quit {"last_step": T}`` so that every other actor ends its loop after step T. Pausing
only delays steps, so a lockstep run learns the same whether paused or not.
"""

from __future__ import annotations

import time

import trio

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber, declare_alive
from qlap_runtime.bus.replay import ReplayLog
from qlap_runtime.bus.schema import Control, Sense, WorldView

from .common import ControlError, Controls, RunContext, RunControl, StepInbox

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
                Publisher(session, ctx.run_id, "world") as view, \
                ReplayLog(session, ctx.run_id, "sense", ctx.replay_keep) as replay, \
                Controls(session, ctx, counter) as controls, \
                Publisher(session, ctx.run_id, "control") as end_marker:
            start = ctx.start
            inbox = StepInbox(sub, first=start)
            last_view = 0.0
            if ready is not None:
                await ready.wait()
            hz = float(ctx.extra.get("hz", 100.0)) if ctx.realtime else 0.0
            period = 1.0 / hz if ctx.realtime else 0.0
            rc = RunControl(speed=hz, default_speed=hz)
            tick0 = trio.current_time()
            tick = 0
            pace0 = (tick0, start)          # lockstep pacing: step s is due at t0 + (s - s0)/x
            paused_s = 0.0
            lateness: list[float] = []

            async def gate(t: int) -> bool:
                """Apply the pending controls, then wait while paused or ahead of the set pace
                (a control arriving meanwhile is applied at once); False: quit."""
                nonlocal tick0, tick, period, pace0, paused_s
                rebase = False
                while True:
                    for c in controls.take():
                        try:
                            rebase = rc.apply(c) or rebase
                        except ControlError as e:
                            counter.reject(controls.key, f"{c.command}: {e}")
                    if rc.quit:
                        return False
                    if not rc.may_step:
                        t0 = time.perf_counter()
                        await controls.wait()
                        paused_s += time.perf_counter() - t0
                        rebase = True
                        continue
                    if rebase:              # the clock restarts from now: no catching up
                        rebase = False
                        pace0 = (trio.current_time(), t)
                        if ctx.realtime:
                            period, tick0, tick = 1.0 / rc.speed, pace0[0], 0
                    if not ctx.realtime and rc.speed > 0 and not rc.paused:
                        deadline = pace0[0] + (t - pace0[1]) / rc.speed
                        if trio.current_time() < deadline:
                            with trio.move_on_at(deadline) as pacing:
                                await controls.wait()
                            if not pacing.cancelled_caught:
                                continue    # a control came first
                    return True

            last = start - 1
            loop_t0 = time.perf_counter()
            for t in range(start, start + ctx.steps):
                if (controls.pending or not rc.may_step
                        or (rc.speed > 0 and not ctx.realtime)) and not await gate(t):
                    break
                if ctx.realtime:
                    # §4 realtime: tick at a fixed rate; a tick more than one period late is
                    # missed (skipped, counted); the motor not back by the next deadline is
                    # replaced by the previous one (a late tick).
                    deadline = tick0 + tick * period
                    now = trio.current_time()
                    if now > deadline + period:
                        skipped = int((now - deadline) // period)
                        stats["missed_ticks"] = stats.get("missed_ticks", 0) + skipped
                        tick += skipped
                        deadline = tick0 + tick * period
                    await trio.sleep_until(deadline)
                    lateness.append(trio.current_time() - deadline)
                    tick += 1
                values = dict(obs)
                values.update(applied)
                sense = Sense(t, values, bool(getattr(world, "discontinuity", False)))
                pub.put(sense)
                replay.append(t, sense)             # for a perception actor restarted later
                t0 = time.perf_counter()
                if ctx.realtime:
                    motor = None
                    with trio.move_on_at(tick0 + tick * period):   # the next tick's deadline
                        motor = await inbox.get(t)
                    if motor is None:
                        stats["late_ticks"] = stats.get("late_ticks", 0) + 1
                    for old in [k for k in inbox.buf if k <= t]:
                        del inbox.buf[old]          # motors that came after their deadline
                else:
                    motor = await inbox.get(t)
                stats["wait_s"] += time.perf_counter() - t0
                if motor is not None:
                    applied = dict(motor.values)
                obs = world.step(applied)
                now = time.perf_counter()
                if now - last_view >= 0.1:                    # the UI's world panel, 10 Hz
                    last_view = now
                    view.put(WorldView(t, str(getattr(world, "name", ctx.world)),
                                       world.render_text(44, 14),
                                       {k: float(v) for k, v in obs.items()}, applied, {}))
                stats["steps"] += 1
                rc.stepped()
                last = t
            if rc.quit:
                # The end marker: every other actor ends after step `last` (the last one whose
                # sense was published and whose motor was applied) and writes its outputs.
                end_marker.put(Control("quit", {"last_step": last}))
                stats["quit_at_step"] = last
            # The step chain's own rate, start-up (imports, sessions, waiting for the other
            # actors) and pauses excluded: what the benchmarks compare between placements.
            stats["loop_s"] = round(time.perf_counter() - loop_t0 - paused_s, 3)
            stats["paused_s"] = round(paused_s, 3)
    finally:
        world.close()
    stats["rejected"] = counter.snapshot().total
    if ctx.realtime and lateness:
        ms = sorted(x * 1e3 for x in lateness)
        stats.update(hz=1.0 / period, late_ticks=stats.get("late_ticks", 0),
                     missed_ticks=stats.get("missed_ticks", 0),
                     lateness_p50_ms=round(ms[len(ms) // 2], 3),
                     lateness_p99_ms=round(ms[min(len(ms) - 1, int(len(ms) * 0.99))], 3),
                     lateness_max_ms=round(ms[-1], 3))
    return stats

