"""The hosted step chain's hops in memory (docs/decisions.md 83–84).

When world, perception and executor share a process (``RunContext.together``), the world's
task runs the three steps in turn (decision 52) and each hands the next its step's value here:
``sense(t)`` to perception, the percept of step t (perceived once, with the executor's own
learner's perception) to the executor, ``motor(t)`` back to the world. The bus carries the same
messages beside the chain, for whoever else listens (a recorder, the UI, the learners of
another process) and for the replay logs those consumers may ask; the chain never waits on it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import trio

from qlap_runtime.bus.schema import Motor, Sense
from qlap_runtime.qlap.perception import Percept

YIELD_S = 0.001
"""The hosted step chain lets the run's other tasks (learners, planner, controls, viewers) run
at least this often (docs/decisions.md 85): a trio checkpoint is a turn of the scheduler with
an epoll poll, which every step paid."""


@dataclass
class Chain:
    """One step's values between the hosted actors, each written before the next reads it."""

    sense: Sense | None = None
    """``sense(t)``, from the world to perception."""
    percept: Percept | None = None
    """The percept of step t, from perception to the executor: already remembered by the
    executor's learner's perception (``ModelLearner.observe_own``); None when step t was
    rejected."""
    rejected: str = ""
    """Why step t was rejected (its ``qstate``'s reason), or empty."""
    motor: Motor | None = None
    """``motor(t)``, from the executor to the world."""
    last_yield: float = 0.0

    async def step(self, t: int, sense: Sense, perception: Any, executor: Any) -> Motor | None:
        """Step t after ``sense(t)``: the perception actor's step, the executor's, and
        ``motor(t)`` back (None: the executor took no step); at least every :data:`YIELD_S`
        the run's other tasks get the loop."""
        self.sense = sense
        await perception.step(t)
        await executor.step(t)
        if (now := time.perf_counter()) - self.last_yield >= YIELD_S:
            self.last_yield = now
            await trio.lowlevel.checkpoint()    # learners, controls, viewers
        motor, self.motor = self.motor, None
        return motor

    def perceived(self, percept: Percept | None, rejected: str = "") -> None:
        self.percept, self.rejected = percept, rejected

    def percept_of(self, t: int) -> Percept:
        """The percept of step ``t`` (a step not rejected), which the perception actor wrote."""
        if self.percept is None or self.percept.step != t:
            raise RuntimeError(f"the hosted step chain has no percept of step {t}")
        return self.percept
