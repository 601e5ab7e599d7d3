"""A one-motor world written for the tests (numpy only, no physics engine).

u ∈ [−1, 1] moves x only when |u| > 0.3 (x += 0.5·u per step), and x is bounded in [0, 10].
The motor value chosen at step t acts on x between t and t + 1, as in the agent loop.
:class:`ToyTaskWorld` adds one evaluation task (§7.2.1) for ``worlds.evaluate.run_trials``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worlds.base import Goal, Task


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


class ToyTaskWorld:
    """:class:`ToyWorld` with the evaluation interface of ``worlds.evaluate.run_trials``: one
    task, "x_up" (goal ẋ = [+], §7.2.1), whose trials start with x uniform in [1, 9]."""

    name = "toy"

    def __init__(self) -> None:
        self.world = ToyWorld()
        self.prev = self.world.x
        self.step_count = 0
        self.discontinuity = False
        self.tasks = {"x_up": XUp()}

    def step(self, motor) -> dict[str, float]:
        self.prev = self.world.x
        self.world.step(float(motor["u"]))
        self.step_count += 1
        self.discontinuity = False
        return {"x": self.world.x}


class XUp(Task):
    name = "x_up"
    max_steps = 50

    def setup(self, world, rng) -> dict[str, float]:
        world.world.x = float(rng.uniform(1.0, 9.0))
        world.prev = world.world.x
        world.step_count = 0
        world.discontinuity = True                  # a new trial is a jump
        return {"x": world.world.x}

    def goal(self, world, obs) -> Goal:
        return Goal("x.dot", "+")

    def is_success(self, world, obs) -> bool:
        return obs["x"] - world.prev > 0.1
