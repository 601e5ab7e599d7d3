"""``World.get_state``/``set_state``: the exact resume of every world (docs/decisions.md 41).

MuJoCo's core saves ``mj_getState`` plus what the world changes in its model; pong its few
numbers; core2d (pymunk) and the Gymnasium worlds replay the motor commands since ``reset``.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from worlds import check_world, make
from worlds.check import random_motor
from worlds.pong.world import PongWorld


def _trace(world: Any, motors: list[dict[str, float]]) -> list[tuple[dict, bool]]:
    return [(world.step(m), world.discontinuity) for m in motors]


@pytest.mark.parametrize("spec", ["core", "core:secondary:unaligned", "core:contingent:jump",
                                  "core2d", "pong"])
def test_a_fresh_world_continues_exactly_after_a_long_run(spec: str) -> None:
    """2,000 steps of babbling-like motors (held 0..40 steps, so that grasps, pushes, falls
    and replacements happen), saved through JSON and restored into a new instance made with
    the same spec: the next 1,000 observations and flags are identical."""
    rng = np.random.default_rng(3)
    world = make(spec)
    world.reset(seed=11)
    motors, m = [], random_motor(world, rng)
    for i in range(3000):
        if i % int(rng.integers(1, 40)) == 0:
            m = random_motor(world, rng)
        motors.append(dict(m))
    _trace(world, motors[:2000])
    text = json.dumps(world.get_state(), allow_nan=False)
    expected = _trace(world, motors[2000:])
    fresh = make(spec)
    fresh.reset(seed=999)
    fresh.set_state(json.loads(text))
    assert fresh.step_count == 2000
    assert _trace(fresh, motors[2000:]) == expected
    assert sum(flag for _, flag in expected) >= (1 if spec != "pong" else 0)


@pytest.mark.parametrize("spec", ["core", "core2d", "pong"])
def test_a_corrupt_state_is_a_value_error_naming_it(spec: str) -> None:
    world = make(spec)
    world.reset(seed=1)
    world.step({})
    good = json.loads(json.dumps(world.get_state()))
    bad_states = [
        ({**good, "format": "x"}, "not a world state"),
        ({**good, "version": 9}, "version 9"),
        ({**good, "world": "mars"}, "'mars'"),
        ({**good, "step_count": -3}, "-3"),
    ]
    if "replay" in good:
        bad_states.append(({**good, "replay": {**good["replay"], "motors": "!!"}}, "corrupt"))
        bad_states.append(({**good, "step_count": 5}, "holds 1 steps"))
    else:
        physics = dict(good["physics"])
        key = "mj_state" if "mj_state" in physics else "ball"
        physics[key] = physics[key][:-1]
        bad_states.append(({**good, "physics": physics}, key))
    for state, fragment in bad_states:
        with pytest.raises((ValueError, KeyError, TypeError), match=fragment):
            world.set_state(state)


def test_a_replayed_world_refuses_to_save_after_a_caller_moved_things() -> None:
    world = make("core2d")
    world.reset(seed=1)
    world.set_hand(1.0, 1.0)
    with pytest.raises(ValueError, match="placed by a caller"):
        world.get_state()
    world.reset(seed=1)                         # a run from reset replays again
    assert world.get_state()["step_count"] == 0


class _Forgetful(PongWorld):
    """A pong whose saved state forgets the ball's velocity."""

    def _set_state(self, physics: Any) -> None:
        super()._set_state({**physics, "ball_v": [0.4, 0.1]})


def test_check_world_catches_a_state_that_does_not_round_trip() -> None:
    with pytest.raises(AssertionError, match="after set_state the run differs"):
        check_world(_Forgetful(), steps=300, seed=0)
