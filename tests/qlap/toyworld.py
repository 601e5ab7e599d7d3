"""A one-motor world written for the tests (numpy only, no physics engine).

u ∈ [−1, 1] moves x only when |u| > 0.3 (x += 0.5·u per step), and x is bounded in [0, 10].
The motor value chosen at step t acts on x between t and t + 1, as in the agent loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Spec:
    name: str
    kind: str
    low: float | None = None
    high: float | None = None
    values: tuple[str, ...] = ()
    available_from: int = 0


SPECS = (Spec("u", "motor", -1.0, 1.0), Spec("x", "magnitude"))
THRESHOLD = 0.3


class ToyWorld:
    def __init__(self, x0: float = 5.0) -> None:
        self.x = x0

    def step(self, u: float) -> None:
        if abs(u) > THRESHOLD:
            self.x = float(np.clip(self.x + 0.5 * u, 0.0, 10.0))


def babble_stream(steps: int, seed: int):
    """Yield (step, observation) with App. E babbling on u."""
    from qlap_runtime.qlap import Params, VariableTable
    from qlap_runtime.qlap.babble import Babbler

    table = VariableTable.from_specs(SPECS)
    babbler = Babbler(table, Params(), np.random.default_rng(seed))
    world = ToyWorld()
    for t in range(steps):
        motor, _ = babbler.step()
        yield t, {"u": motor["u"], "x": world.x}
        world.step(motor["u"])
