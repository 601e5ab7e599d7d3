"""``World.discontinuity`` and ``World.step_seconds``: every world marks its teleports and says how
long a step lasts; tasks judge directions of change per second, as the agent's perception does."""

from __future__ import annotations

import numpy as np
import pytest

from worlds import DOT_BAND, check_world, direction, make
from worlds.core import world as core
from worlds.pong.world import PongWorld

from .conftest import Babble


@pytest.mark.parametrize(
    ("spec", "seconds"),
    [
        ("core", 0.05),
        ("core:floating", 0.05),
        ("core:secondary:aligned", 0.05),
        ("core2d", 0.05),
        ("pong", 1.0),
        ("gym:Pendulum-v1", 0.05),  # the env's dt
        ("gym:MountainCarContinuous-v0", 1.0),  # no dt: a step is the time unit
    ],
)
def test_step_seconds(spec: str, seconds: float) -> None:
    world = make(spec)
    try:
        assert world.step_seconds == seconds
        assert isinstance(world.step_seconds, float)
    finally:
        world.close()
    assert core.TIMESTEP * core.SUBSTEPS == 0.05  # two MuJoCo steps of 0.025 s


def test_direction_is_per_second_with_the_references_closed_band() -> None:
    assert DOT_BAND == 0.05  # Table 8.1: [−0.05, 0.05] on every change variable
    # Δh_x ≈ 0.46 per step is ḣ_x ≈ 9.2 (Table 8.9): far outside the band.
    assert direction(1.55, 2.01, dt=0.05) == "+"
    assert direction(0.0, 0.003, dt=0.05) == "+"  # 0.06 per second
    assert direction(0.0, 0.002, dt=0.05) == "0"  # 0.04 per second
    assert direction(0.0, -0.003, dt=0.05) == "-"
    assert direction(0.0, 0.05) == "0"  # the band is closed, as the perception's landmark
    assert direction(0.0, 0.0500001) == "+"


def test_change_is_none_on_a_discontinuity() -> None:
    world = make("core")
    world.reset(seed=0)
    assert world.discontinuity is True
    assert world.change("h_x") is None
    world.step({"u_x": 1000.0})
    assert world.discontinuity is False
    assert world.change("h_x") == "+"
    assert world.change("T_L") == "0"


def test_core_teleports_between_steps_mark_the_next_step() -> None:
    world = make("core")
    assert isinstance(world, core.CoreWorld)
    world.reset(seed=0)
    assert world.discontinuity is True
    world.step({})
    assert world.discontinuity is False
    world.set_hand(1.0, 1.0, 13.0)
    assert world.discontinuity is False  # the latest observation is still the old one
    world.step({})
    assert world.discontinuity is True
    world.step({})
    assert world.discontinuity is False
    world.place_block(np.random.default_rng(0))
    world.step({})
    assert world.discontinuity is True


@pytest.mark.parametrize("task", ["move_block", "hit_floor", "pickup"])
def test_a_task_set_up_starts_a_fresh_stream(task: str) -> None:
    world = make("core")
    rng = np.random.default_rng(3)
    obs = world.tasks[task].setup(world, rng)
    assert world.discontinuity is True
    assert world.observation == world.previous_observation
    assert obs == world.observation
    world.step({})
    assert world.discontinuity is False  # hand and block were placed before the first obs


@pytest.mark.parametrize("spec", ["core", "core:secondary:unaligned", "core2d"])
def test_discontinuity_exactly_on_replacement_steps(spec: str, babble: Babble) -> None:
    """In a babbling run the block is replaced (fell, out of reach, moved after a let-go) on
    some steps; those and only those are discontinuities, and on the others the block moves
    continuously."""
    world = make(spec)
    world.reset(seed=2)
    flagged = 0
    for obs in babble(world, 4000, seed=2):
        prev = world.previous_observation
        replaced = world.block_replaced  # type: ignore[attr-defined]
        assert world.discontinuity is replaced
        flagged += replaced
        if not world.discontinuity:
            key = "x_RL" if "x_RL" in obs else "h_x"
            moved = abs((obs[key] - obs["h_x"]) - (prev[key] - prev["h_x"]))
            assert moved < 0.8  # the block's x moved at most about the hand's top speed
    assert flagged >= 5


def test_bang_then_replacement_is_a_discontinuity() -> None:
    world = make("core")
    assert isinstance(world, core.CoreWorld)
    world.reset(seed=4)
    world.place_block(np.random.default_rng(4), x=2.6, y=0.0, width=1.0)
    world.set_hand(0.5, 0.0, 11.0)
    for _ in range(80):
        obs = world.step({"u_x": 700.0})
        if obs["bang"] == 1.0:
            break
    assert obs["bang"] == 1.0
    assert not world.discontinuity  # the fall itself is continuous
    world.step({})
    assert world.block_replaced
    assert world.discontinuity


def test_pong_recentring_is_a_discontinuity(babble: Babble) -> None:
    world = make("pong")
    assert isinstance(world, PongWorld)
    world.reset(seed=0)
    missed_before = False
    restarts = 0
    for _ in babble(world, 3000, seed=0):
        assert world.discontinuity is missed_before
        restarts += world.discontinuity
        missed_before = world.missed
    assert restarts >= 10


def test_gym_episode_restart_is_a_discontinuity() -> None:
    world = make("gym:Pendulum-v1")
    try:
        world.reset(seed=0)
        rng = np.random.default_rng(0)
        flagged = []
        for t in range(1, 451):
            world.step({"torque": float(rng.uniform(-2, 2))})
            if world.discontinuity:
                flagged.append(t)
        assert flagged == [200, 400]  # Pendulum-v1 is truncated after 200 steps
    finally:
        world.close()


class _Silent(PongWorld):
    """A pong that re-centres the ball without saying so."""

    def _mark_discontinuity(self) -> None:
        pass


def test_check_world_catches_an_unmarked_teleport() -> None:
    with pytest.raises(AssertionError, match="jumped by .* but discontinuity was False"):
        check_world(_Silent(), steps=300, seed=0)


def test_check_world_requires_step_seconds_and_a_bool_flag() -> None:
    world = make("pong")
    world.step_seconds = 0.0
    with pytest.raises(AssertionError, match="step_seconds"):
        check_world(world)

    class NotBool(PongWorld):
        def _step(self, motor: list[float]) -> dict[str, float]:
            obs = super()._step(motor)
            self._jumped = 0  # type: ignore[assignment]
            return obs

    with pytest.raises(AssertionError, match="discontinuity is 0, not a bool"):
        check_world(NotBool())
