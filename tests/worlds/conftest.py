"""Shared helpers of the world tests."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from worlds import VarKind, World

Babble = Callable[[World, int, int], Iterator[dict[str, float]]]


def babble(world: World, steps: int, seed: int) -> Iterator[dict[str, float]]:
    """Motor babbling as in Appendix E: each motor holds a uniform random value for 0..40 steps."""
    rng = np.random.default_rng(seed)
    motors = [v for v in world.variables if v.kind is VarKind.MOTOR]
    values = {m.name: 0.0 for m in motors}
    left = {m.name: -1 for m in motors}
    for _ in range(steps):
        for m in motors:
            if left[m.name] < 0:
                assert m.low is not None
                assert m.high is not None
                values[m.name] = float(rng.uniform(m.low, m.high))
                left[m.name] = int(rng.integers(0, 41))
            left[m.name] -= 1
        yield world.step(values)


@pytest.fixture(name="babble")
def babble_fixture() -> Babble:
    """Appendix E's motor babbling, ``babble(world, steps, seed)``: a generator of observations."""
    return babble
