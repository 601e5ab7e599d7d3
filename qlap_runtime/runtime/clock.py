"""The world's clocks: when the world may take its next step (docs/architecture.md §2).

Both obey the clock commands of ``control`` between two steps (:class:`~.controls.RunControl`:
pause, resume, step, speed, quit), waiting while paused without counting it as a stall.

- :class:`LockstepClock`: the world steps as soon as it has the motor of the previous step;
  ``speed x`` paces it at x steps/s (step s due at t0 + (s − s0)/x, restarted from now after
  every command, so a pause is never caught up).
- :class:`RealtimeClock`: the world ticks at a fixed rate (``hz``; ``speed x`` changes it); a
  tick more than one period late is *missed* (skipped and counted); a motor not back by the
  next tick is *late* (the previous one is applied again). It records each tick's lateness.

Time is trio's, so the tests run them on ``trio.testing.MockClock``.
"""

from __future__ import annotations

import gc
import sys
import time
from typing import Any

import trio
from trio.testing import MockClock

from .controls import ControlError, Controls, RunControl
from .inbox import StepInbox
from .watchdog import Slot


def world_clock(realtime: bool, hz: float, controls: Controls, counter: Any,
                slot: Slot | None = None) -> LockstepClock:
    """The world's clock of a run: :class:`RealtimeClock` at ``hz``, or :class:`LockstepClock`."""
    if realtime:
        return RealtimeClock(controls, counter, slot, hz)
    return LockstepClock(controls, counter, slot)


class LockstepClock:
    """The world's clock in lockstep (see the module docstring)."""

    def __init__(self, controls: Controls, counter: Any, slot: Slot | None = None,
                 speed: float = 0.0) -> None:
        self.controls, self.counter = controls, counter
        self.slot = slot if slot is not None else Slot()
        self.state = RunControl(speed=speed, default_speed=speed)
        self.paused_s = 0.0
        """Wall seconds spent paused (excluded from the step chain's rate)."""
        self.wait_s = 0.0
        """Wall seconds spent waiting for motors."""
        self.pace0: tuple[float, int] = (trio.current_time(), 0)
        self.loop_t0 = time.perf_counter()
        self.loop_cpu0 = time.thread_time()

    def start(self, step: int) -> None:
        """The first step is ``step``, now. What start-up allocated is frozen: never scanned
        again by a full garbage collection (docs/decisions.md 61, 85: 31–37 ms each on core's
        embedded placement, 0.37 s in a 30,000-step lockstep run against 0.13 s for the
        synchronous loop's)."""
        gc.collect()
        gc.freeze()
        self.rebase(step)
        self.loop_t0 = time.perf_counter()
        self.loop_cpu0 = time.thread_time()

    def stop(self) -> dict[str, Any]:
        """The loop is over: its own time (start-up and pauses excluded: the step chain's rate
        the benchmarks compare), the time paused, and the CPU time of this thread over the
        loop (``loop_cpu_s``: the hosted step chain's own work); start-up's objects may be
        collected again."""
        gc.unfreeze()
        loop_s = time.perf_counter() - self.loop_t0
        return {"loop_s": round(loop_s - self.paused_s, 3), "paused_s": round(self.paused_s, 3),
                "wait_s": self.wait_s,
                "loop_cpu_s": round(time.thread_time() - self.loop_cpu0, 3)}

    def rebase(self, step: int) -> None:
        """The clock restarts at ``step``, now: no catching up."""
        self.pace0 = (trio.current_time(), step)

    def paced(self) -> bool:
        """Whether steps are paced (a gate before every step)."""
        return self.state.speed > 0

    async def before(self, t: int) -> bool:
        """Wait until step ``t`` may be taken; False: the run was quit."""
        rc = self.state
        if self.controls.pending or not rc.may_step or self.paced():
            return await self._gate(t)
        return True

    async def motor(self, inbox: StepInbox, t: int) -> Any:
        """The motor of step ``t`` (the wait is added to :attr:`wait_s`)."""
        t0 = time.perf_counter()
        try:
            return await self.take_motor(inbox, t)
        finally:
            self.wait_s += time.perf_counter() - t0

    async def take_motor(self, inbox: StepInbox, t: int) -> Any:
        """The motor of step ``t``: waited for."""
        return await inbox.get(t)

    def stepped(self) -> None:
        """A step was taken (uses up a ``step`` budget)."""
        self.state.stepped()

    async def _gate(self, t: int) -> bool:
        """Apply the pending controls, then wait while paused or ahead of the pace (a control
        arriving meanwhile is applied at once)."""
        rc, rebase = self.state, False
        while True:
            for c in self.controls.take():
                try:
                    rebase = rc.apply(c) or rebase
                except ControlError as e:
                    self.counter.reject(self.controls.key, f"{c.command}: {e}")
            if rc.quit:
                return False
            if not rc.may_step:
                t0 = time.perf_counter()
                await self._paused()
                self.paused_s += time.perf_counter() - t0
                rebase = True
                continue
            if rebase:
                rebase = False
                self.rebase(t)
            if not await self._pace(t):
                continue                            # a control came first
            return True

    async def _paused(self) -> None:
        """Wait for a control while paused."""
        with self._not_a_stall():
            await self.controls.wait()

    async def _pace(self, t: int) -> bool:
        """Wait for step ``t``'s turn at the set pace; False if a control came first."""
        rc = self.state
        if rc.speed <= 0 or rc.paused:
            return True
        deadline = self.pace0[0] + (t - self.pace0[1]) / rc.speed
        if trio.current_time() >= deadline:
            return True
        with self._not_a_stall(), trio.move_on_at(deadline) as pacing:
            await self.controls.wait()
        return pacing.cancelled_caught

    def _not_a_stall(self) -> Any:
        slot = self.slot

        class _Paused:
            def __enter__(self) -> None:
                slot.paused(True)               # no progress expected: not a stall

            def __exit__(self, *exc: object) -> None:
                slot.paused(False)
        return _Paused()

    def stats(self) -> dict[str, Any]:
        return {}


PRECISE_S = 0.0012
"""The last part of a tick's wait is a plain sleep of the thread (:func:`time.sleep`, to the
microsecond) instead of trio's: the I/O wait under trio's sleep takes whole milliseconds,
rounded up, which made a tick 0.7 ms late on average and up to 1 ms."""
NO_FULL_COLLECTION = 1 << 30
"""The garbage collector's third threshold under the realtime clock: so many young
collections before a full one that none comes (:meth:`RealtimeClock.collect_fully`)."""
SWITCH_INTERVAL_S = 0.0005
"""The GIL switch interval under the realtime clock (Python's default is 5 ms)."""
MISSED_AT_KEPT = 20
"""How many places of missed ticks the realtime clock's summary lists."""


async def sleep_until_precisely(deadline: float) -> None:
    """Sleep until trio time ``deadline``: with trio until :data:`PRECISE_S` before it (other
    tasks run), then the rest with the thread blocked (the GIL released), returning without a
    checkpoint. Under ``trio.testing.MockClock`` the last part is trio's too (the mock clock
    jumps to it)."""
    await trio.sleep_until(deadline - PRECISE_S)
    if isinstance(trio.lowlevel.current_clock(), MockClock):
        await trio.sleep_until(deadline)
        return
    rest = deadline - trio.current_time()
    if rest > 0:
        # Blocking on purpose, for at most PRECISE_S: a checkpoint after it would let other
        # tasks run first.
        time.sleep(rest)  # noqa: ASYNC251


class RealtimeClock(LockstepClock):
    """The world's clock at a fixed tick rate (see the module docstring)."""

    def __init__(self, controls: Controls, counter: Any, slot: Slot | None = None,
                 hz: float = 100.0) -> None:
        super().__init__(controls, counter, slot, speed=hz)
        self.period = 1.0 / hz
        self.tick0 = trio.current_time()
        self.tick = 0
        self.missed = 0
        self.woke = self.tick0
        """When the loop last woke up for its tick."""
        self.missed_at: list[tuple[int, float, float]] = []
        """Where ticks were skipped: (step, how late the loop woke for the step before, in
        ms, and how long it then took to come back, in ms). A late wake-up is the machine (or
        another process on the cores); a long way back is the step's own work."""
        self.late = 0
        self.lateness: list[float] = []
        self.switch_interval = sys.getswitchinterval()
        self.thresholds = gc.get_threshold()
        self.full_collections = 0
        """Full garbage collections run at safe points (paused, the end of the loop)."""
        self.collected = 0
        """Objects those collections freed: the cyclic garbage the loop left to them."""

    def start(self, step: int) -> None:
        """The first tick is now. Start-up is frozen (:meth:`LockstepClock.start`: a full
        collection took 31–37 ms, three missed ticks), and a thread that holds the GIL gives
        it up after :data:`SWITCH_INTERVAL_S` when the clock's thread wants it."""
        self.switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self.switch_interval, SWITCH_INTERVAL_S))
        super().start(step)
        gc.set_threshold(self.thresholds[0], self.thresholds[1], NO_FULL_COLLECTION)

    def stop(self) -> dict[str, Any]:
        """The loop is over: the GIL switch interval and the garbage collector's thresholds
        are Python's again, after the full collection the loop deferred."""
        sys.setswitchinterval(self.switch_interval)
        self.collect_fully()
        gc.set_threshold(*self.thresholds)
        return super().stop()

    def collect_fully(self) -> None:
        """A full garbage collection now, at a safe point (docs/decisions.md 102): under the
        realtime clock none runs by itself, since one scans every object the run made since
        start-up — 64–104 ms for core at 4,000 ticks, eight missed ticks at 100 Hz — while a
        young collection takes well under a millisecond."""
        self.collected += gc.collect()
        self.full_collections += 1

    async def _paused(self) -> None:
        self.collect_fully()                    # no tick is due while paused
        await super()._paused()

    def rebase(self, step: int) -> None:
        super().rebase(step)
        self.period, self.tick0, self.tick = 1.0 / self.state.speed, self.pace0[0], 0

    def paced(self) -> bool:
        return False                                # the ticks pace it

    async def _pace(self, t: int) -> bool:
        return True

    async def before(self, t: int) -> bool:
        """Apply controls, then wait for the next tick (skipping those more than one period
        late); False: the run was quit."""
        if not await super().before(t):
            return False
        deadline = self.tick0 + self.tick * self.period
        now = trio.current_time()
        if now > deadline + self.period:
            skipped = int((now - deadline) // self.period)
            self.missed += skipped
            woke_late = self.lateness[-1] if self.lateness else 0.0
            self.missed_at.append((t, round(woke_late * 1e3, 1), round((now - self.woke) * 1e3, 1)))
            self.tick += skipped
            deadline = self.tick0 + self.tick * self.period
        await sleep_until_precisely(deadline)
        self.woke = trio.current_time()
        self.lateness.append(self.woke - deadline)
        self.tick += 1
        return True

    async def take_motor(self, inbox: StepInbox, t: int) -> Any:
        """The motor of step ``t`` if it is back by the next tick, else None (late)."""
        motor = None
        with trio.move_on_at(self.tick0 + self.tick * self.period):
            motor = await inbox.get(t)
        if motor is None:
            self.late += 1
        inbox.drop_before(t + 1)                    # motors that came after their deadline
        return motor

    def stats(self) -> dict[str, Any]:
        """The summary's tick figures: rate, late and missed ticks, lateness percentiles."""
        if not self.lateness:
            return {}
        ms = sorted(x * 1e3 for x in self.lateness)
        return {"hz": 1.0 / self.period, "late_ticks": self.late, "missed_ticks": self.missed,
                "missed_at": [list(m) for m in self.missed_at[:MISSED_AT_KEPT]],
                "full_collections": self.full_collections, "gc_collected": self.collected,
                "lateness_p50_ms": round(ms[len(ms) // 2], 3),
                "lateness_p99_ms": round(ms[min(len(ms) - 1, int(len(ms) * 0.99))], 3),
                "lateness_max_ms": round(ms[-1], 3)}
