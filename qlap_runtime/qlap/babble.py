"""Motor babbling (Appendix E).

Each motor holds a uniformly random value within its range for a random number of steps drawn
uniformly from 0..``Params.babble_max_hold``; motors change at different times so that the model
learner does not see spurious correlations between them.
"""

from __future__ import annotations

import numpy as np

from .params import Params
from .variables import Kind, VariableTable


class Babbler:
    """Per-motor random values with independent hold counters (Appendix E)."""

    def __init__(self, table: VariableTable, params: Params, rng: np.random.Generator) -> None:
        self.motors = table.of_kind(Kind.MOTOR)
        self.params = params
        self.rng = rng
        self.values = np.zeros(len(self.motors))
        self.counters = np.zeros(len(self.motors), dtype=np.int64)
        self.limits = np.full(len(self.motors), -1, dtype=np.int64)

    def step(self) -> tuple[dict[str, float], bool]:
        """The motor command of this step, and whether some motor's counter hit its maximum
        (which ends one babbling command during exploration, Appendix E)."""
        expired = self.counters > self.limits
        for i in np.flatnonzero(expired):
            m = self.motors[i]
            self.values[i] = self.rng.uniform(m.low, m.high)
            self.limits[i] = self.rng.integers(0, self.params.babble_max_hold + 1)
            self.counters[i] = 0
        self.counters += 1
        done = bool((self.counters > self.limits).any())
        return {m.name: float(v) for m, v in zip(self.motors, self.values, strict=True)}, done

    def restart(self) -> None:
        """A new episode: every hold counter restarts, so the next :meth:`step` draws a fresh
        value and hold for every motor (nothing held over from before the discontinuity)."""
        self.values = np.zeros(len(self.motors))
        self.counters = np.zeros(len(self.motors), dtype=np.int64)
        self.limits = np.full(len(self.motors), -1, dtype=np.int64)

    def to_state(self) -> dict:
        return {"values": self.values.tolist(), "counters": self.counters.tolist(),
                "limits": self.limits.tolist()}

    def load_state(self, d: dict) -> None:
        self.values = np.array(d["values"], dtype=float)
        self.counters = np.array(d["counters"], dtype=np.int64)
        self.limits = np.array(d["limits"], dtype=np.int64)
