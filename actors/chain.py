"""The hosted step chain's hops in memory (docs/decisions.md 83–84).

When world, perception and executor share a process (``RunContext.together``), the world's
task runs the three steps in turn (decision 52) and each hands the next its step's value here:
``sense(t)`` to perception, the percept of step t (perceived once, with the executor's own
learner's perception) to the executor, ``motor(t)`` back to the world. The bus carries the same
messages beside the chain, for whoever else listens (a recorder, the UI, the learners of
another process) and for the replay logs those consumers may ask; the chain never waits on it.
"""

from __future__ import annotations

from dataclasses import dataclass

from qlap_runtime.bus.schema import Motor, Sense
from qlap_runtime.qlap.perception import Percept


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

    def perceived(self, percept: Percept | None, rejected: str = "") -> None:
        self.percept, self.rejected = percept, rejected
