"""The world's clocks on trio's MockClock (autojump): pacing, pause and single steps, quit, and
the realtime clock's ticks, missed ticks and late motors. Controls travel on a real embedded
Zenoh session."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from itertools import pairwise
from typing import Any

import pytest
import trio
from trio.testing import MockClock

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher, RejectionCounter, TrioSubscriber
from qlap_runtime.bus.schema import Control, Motor, encode
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.clock import LockstepClock, RealtimeClock
from qlap_runtime.runtime.context import RunContext
from qlap_runtime.runtime.controls import Controls
from qlap_runtime.runtime.inbox import StepInbox
from qlap_runtime.runtime.watchdog import PAUSED, Slot

CTX = RunContext("clock-test", "core2d", 100, 0, Params())


@pytest.fixture
def clock() -> MockClock:
    return MockClock(autojump_threshold=0)


def put(session: Any, command: str, **args: Any) -> None:
    session.put(keys.key(CTX.run_id, "control"), encode(Control(command, args)))


async def delivered(controls: Controls, n: int) -> None:
    """Wait (without advancing the clock: no deadline) until ``n`` controls have arrived."""
    while controls.received < n:
        await controls.wait()


@contextlib.contextmanager
def started_realtime_clock(session: Any) -> Iterator[tuple[RealtimeClock, dict[str, Any]]]:
    """A :class:`RealtimeClock` at 100 Hz on ``session``'s controls, started at step 0 and
    stopped at the end; the dict holds the ``controls`` and, once stopped, ``stats``."""
    counter = RejectionCounter("world")
    with Controls(session, CTX, counter) as controls:
        rt = RealtimeClock(controls, counter, hz=100.0)
        rt.start(0)
        held: dict[str, Any] = {"controls": controls}
        try:
            yield rt, held
        finally:
            held["stats"] = rt.stop()


async def test_lockstep_is_free_until_paced_then_steps_at_the_set_rate(embedded, clock):
    counter = RejectionCounter("world")
    with Controls(embedded, CTX, counter) as controls:
        lc = LockstepClock(controls, counter)
        lc.start(0)
        t0 = trio.current_time()
        for t in range(5):                      # free: no wait at all
            assert await lc.before(t)
        assert trio.current_time() == t0
        put(embedded, "speed", steps_per_s=10)
        await delivered(controls, 1)
        times = []
        for t in range(5, 11):
            assert await lc.before(t)
            times.append(trio.current_time())
        gaps = [round(b - a, 6) for a, b in pairwise(times)]
        assert gaps == [0.1] * 5                # 10 steps/s from the command on
        assert lc.state.message == "speed 10 steps/s"


async def test_pause_waits_without_a_stall_single_steps_and_quit(embedded, clock):
    counter = RejectionCounter("world")
    slot = Slot()
    with Controls(embedded, CTX, counter) as controls:
        lc = LockstepClock(controls, counter, slot)
        lc.start(0)
        put(embedded, "pause")
        await delivered(controls, 1)
        took: list[int] = []

        async def world() -> None:
            for t in range(100):
                if not await lc.before(t):
                    return
                took.append(t)
                lc.stepped()

        async with trio.open_nursery() as nursery:
            nursery.start_soon(world)
            await trio.sleep(3600)              # an hour of mock time: paused, no step
            assert took == [] and slot.data[PAUSED] == 1.0
            put(embedded, "step", n=2)
            await delivered(controls, 2)
            await trio.sleep(1)
            assert took == [0, 1]               # exactly two, then paused again
            put(embedded, "step", n="many")     # malformed: refused and counted
            put(embedded, "quit")
        assert took == [0, 1] and lc.state.quit
        assert counter.snapshot().total == 1


async def test_realtime_ticks_counts_missed_ticks_and_late_motors(embedded, clock):
    counter = RejectionCounter("world")
    with Controls(embedded, CTX, counter) as controls, \
            TrioSubscriber(embedded, keys.key(CTX.run_id, "motor"), counter=counter) as sub, \
            Publisher(embedded, CTX.run_id, "motor") as pub:
        rt = RealtimeClock(controls, counter, hz=10.0)
        rt.start(0)
        t0 = trio.current_time()
        inbox = StepInbox(sub, first=0, topic="motor", counter=counter)
        for t in range(3):
            assert await rt.before(t)
            assert trio.current_time() == pytest.approx(t0 + 0.1 * t)
        await trio.sleep(0.35)                  # the world was held up: 2 ticks missed
        assert await rt.before(3)
        assert rt.missed == 2
        assert trio.current_time() == pytest.approx(t0 + 0.55)
        assert await rt.motor(inbox, 3) is None                  # none by the next tick
        assert rt.late == 1
        assert trio.current_time() == pytest.approx(t0 + 0.6)
        assert await rt.before(4)
        pub.put(Motor(4, {"u": 0.5}))
        # Delivered first, with no deadline pending (so the mock clock cannot jump past the
        # tick while Zenoh's thread delivers it in real time): back by the tick.
        for r in await sub.receive_batch():
            inbox.add(r.msg, len(r.payload))
        assert (await rt.motor(inbox, 4)).values == {"u": 0.5}  # back in time
        assert rt.late == 1
        stats = rt.stats()
        assert stats["hz"] == 10.0 and stats["missed_ticks"] == 2 and stats["late_ticks"] == 1
        # Where: before step 3; the loop woke for step 2 on time and came back 350 ms later.
        assert stats["missed_at"] == [[3, 0.0, 350.0]]
        put(embedded, "speed", steps_per_s=20)  # the tick rate follows speed
        await delivered(controls, 1)
        s0 = trio.current_time()
        assert await rt.before(5) and await rt.before(6)
        assert trio.current_time() - s0 == pytest.approx(0.05)


async def test_the_realtime_loop_freezes_start_up_objects_and_shortens_the_gil_switch(
        embedded, clock):
    import gc
    import sys

    before = sys.getswitchinterval()
    with started_realtime_clock(embedded) as (rt, stopped):
        assert gc.get_freeze_count() > 0
        assert sys.getswitchinterval() <= 0.0005
        t0 = trio.current_time()
        assert await rt.before(0) and await rt.before(1)
        assert trio.current_time() == pytest.approx(t0 + 0.01)  # to the tick, mock time
        assert rt.lateness == [0.0, 0.0]
    stats = stopped["stats"]
    assert gc.get_freeze_count() == 0
    assert sys.getswitchinterval() == before
    assert set(stats) == {"loop_s", "paused_s", "wait_s", "loop_cpu_s"}


async def test_the_realtime_loop_defers_full_collections_to_pauses_and_its_end(
        embedded, clock):
    """Decision 102: a full collection mid-run scanned every object made since start-up,
    64–104 ms for core at 4,000 ticks (eight missed ticks at 100 Hz); under the realtime
    clock none runs by itself, and the deferred ones run while paused and at the end."""
    import gc

    class Node:
        pass

    thresholds = gc.get_threshold()
    with started_realtime_clock(embedded) as (rt, stopped):
        assert gc.get_threshold() == (thresholds[0], thresholds[1], 1 << 30)
        held = []
        for _ in range(10):                     # 10 cycles of two nodes
            a, b = Node(), Node()
            a.other, b.other = b, a
            held.append(a)
        gc.collect(1)
        gc.collect(1)                           # survivors of a generation-1 collection: old
        del held, a, b
        assert gc.collect(1) == 0               # young collections do not free them
        put(embedded, "pause")
        await delivered(stopped["controls"], 1)
        async with trio.open_nursery() as nursery:
            nursery.start_soon(rt.before, 0)
            await trio.sleep(1)                 # paused: the deferred full collection
            assert rt.full_collections == 1 and rt.collected >= 20
            put(embedded, "resume")
    assert gc.get_threshold() == thresholds
    assert rt.stats()["full_collections"] == 2          # and one at the end


async def test_the_lockstep_loop_freezes_start_up_objects_too(embedded, clock):
    """Decision 85: a full collection scanned start-up's objects (the session, the libraries'
    and the agent's) in lockstep too, 0.37 s of a 30,000-step embedded run."""
    import gc

    counter = RejectionCounter("world")
    with Controls(embedded, CTX, counter) as controls:
        lc = LockstepClock(controls, counter)
        lc.start(0)
        try:
            assert gc.get_freeze_count() > 0
            assert await lc.before(0)
        finally:
            lc.stop()
        assert gc.get_freeze_count() == 0
