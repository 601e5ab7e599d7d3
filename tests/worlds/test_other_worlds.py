"""core2d, pong and the Gymnasium wrapper."""

from __future__ import annotations

import numpy as np
import pytest

from worlds import VarKind, check_world, make
from worlds.core2d.world import Core2DWorld
from worlds.gym_wrapper import GymWorld
from worlds.pong.world import PongWorld


def test_core2d_friction_threshold_and_push() -> None:
    world = make("core2d")
    assert isinstance(world, Core2DWorld)
    world.reset(seed=0)
    world.set_hand(0.0, 0.5)
    world.block.position = (-3.2, -1.9)  # type: ignore[union-attr]
    start = world.hand.position.x
    for _ in range(40):
        world.step({"u_x": 290.0})
    assert abs(world.hand.position.x - start) < 1e-6
    for _ in range(10):
        obs = world.step({"u_x": 400.0})
    assert world.hand.position.x - start > 0.6  # (400 − 300) / 75 units/s, as in core
    assert obs["h_x"] > start
    world.set_hand(-2.5, 0.5)
    for _ in range(4):
        previous = world.step({"u_x": 1000.0})["h_x"]
    per_step = world.step({"u_x": 1000.0})["h_x"] - previous
    assert per_step == pytest.approx(700 / 75 * world.step_seconds, rel=0.01)  # 0.47


def test_core2d_push_moves_the_block_about_as_far_as_the_hand() -> None:
    world = make("core2d")
    assert isinstance(world, Core2DWorld)
    world.reset(seed=1)
    world.set_hand(-2.0, 0.0)
    world.block.position = (1.0, 0.0)  # type: ignore[union-attr]
    obs = world.step({})
    while obs["x_LR"] < -0.02:
        obs = world.step({"u_x": 1000.0})
    hand0, block0 = obs["h_x"], world.block.position.x  # type: ignore[union-attr]
    for _ in range(3):
        obs = world.step({"u_x": 1000.0})
    hand = obs["h_x"] - hand0
    for _ in range(20):
        obs = world.step({})
        assert not world.discontinuity
    block = world.block.position.x - block0  # type: ignore[union-attr]
    assert hand - 0.02 < block < hand + 0.7
    assert obs["z_F"] == 10.5


def test_core2d_block_pushed_off_the_table_falls_and_is_replaced() -> None:
    world = make("core2d")
    world.reset(seed=1)
    world.set_hand(-1.0, 0.0)  # type: ignore[attr-defined]
    world.block.position = (1.5, 0.0)  # type: ignore[attr-defined]
    z_f = []
    for _ in range(120):
        obs = world.step({"u_x": 600.0})
        z_f.append(obs["z_F"])
        if world.block_replaced:  # type: ignore[attr-defined]
            break
    assert min(z_f) < 1.0  # fell towards the floor
    assert world.block_replaced  # type: ignore[attr-defined]
    assert world.discontinuity
    assert obs["z_F"] == 10.5


def test_pong_ball_reflects_off_a_paddle() -> None:
    world = make("pong")
    assert isinstance(world, PongWorld)
    world.reset(seed=0)
    world.paddle_y = 6.0
    world.ball, world.ball_v = [1.6, 6.2], [-0.4, 0.1]
    obs = world.step({"u": 0.0})
    assert world.hit
    assert world.ball_v[0] > 0
    before = obs["b_x"]
    obs = world.step({"u": 0.0})
    assert obs["b_x"] > before  # now moving right: b_x.dot = [+]
    assert obs["cl_x"] == pytest.approx(1.0 - obs["b_x"])


def test_pong_miss_starts_a_new_volley_in_the_middle() -> None:
    world = make("pong")
    world.reset(seed=0)
    world.paddle_y = 1.5  # type: ignore[attr-defined]
    world.ball, world.ball_v = [1.6, 10.0], [-0.4, 0.0]  # type: ignore[attr-defined]
    for _ in range(10):
        world.step({"u": 0.0})
        if world.missed:  # type: ignore[attr-defined]
            break
    assert world.missed  # type: ignore[attr-defined]
    obs = world.step({"u": 0.0})
    assert abs(obs["b_x"] - 10.0) < 0.5
    assert obs["l_y"] == 6.0


def test_pong_motor_is_three_valued() -> None:
    world = make("pong")
    world.reset(seed=0)
    y = world.observation["l_y"]
    assert world.step({"u": 0.03})["l_y"] == y  # dead band: steady
    assert world.step({"u": 0.7})["l_y"] == y + 0.5
    assert world.step({"u": -1.0})["l_y"] == y


@pytest.mark.parametrize(
    ("env_id", "motors", "sensed"),
    [
        ("Pendulum-v1", ["torque"], ["cos_theta", "sin_theta", "theta_dot"]),
        ("MountainCarContinuous-v0", ["force"], ["position", "velocity"]),
    ],
)
def test_gym_wrapper_on_classic_control(env_id: str, motors: list[str], sensed: list[str]) -> None:
    world = make(f"gym:{env_id}")
    try:
        assert isinstance(world, GymWorld)
        assert [v.name for v in world.variables if v.kind is VarKind.MOTOR] == motors
        assert [v.name for v in world.variables if v.kind is VarKind.MAGNITUDE] == sensed
        motor = world.variables[0]
        assert motor.low is not None
        assert motor.high is not None
        assert motor.low < 0 < motor.high
        check_world(world, steps=100, seed=3)
    finally:
        world.close()


def test_gym_wrapper_restarts_on_truncation_and_takes_names() -> None:
    world = make("gym:Pendulum-v1", obs_names=("c", "s", "w"), act_names=("tau",))
    try:
        assert [v.name for v in world.variables] == ["tau", "c", "s", "w"]
        rng = np.random.default_rng(0)
        world.reset(seed=0)
        for _ in range(450):  # Pendulum-v1 is truncated after 200 steps
            obs = world.step({"tau": float(rng.uniform(-2, 2))})
        assert world.episodes == 3  # type: ignore[attr-defined]
        assert set(obs) == {"c", "s", "w"}
    finally:
        world.close()


def test_gym_wrapper_default_names_and_errors() -> None:
    world = make("gym:CartPole-v1", obs_names=None)
    try:
        assert world.motor_names == ("push",)
        spec = world.variables[0]
        assert (spec.low, spec.high) == (0.0, 1.0)
    finally:
        world.close()
    with pytest.raises(ValueError, match="names"):
        make("gym:Pendulum-v1", obs_names=("a",))


def test_pong_declares_each_magnitudes_resolution_as_its_step_per_tick() -> None:
    """Pong's magnitudes declare their resolution (docs/decisions.md 76): the x positions the
    ball's x step 0.4, the paddles their step 0.5, the ball's y and the paddles' y relative to
    it the ball's mean y step at a serve, 0.225. Measured here on 5,000 random-motor steps;
    the learner keeps to the declared value however its history moves."""
    from qlap_runtime.qlap import ModelLearner, Params

    world = make("pong")
    declared = {v.name: v.resolution for v in world.variables if v.kind is VarKind.MAGNITUDE}
    assert declared == {"l_x": 0.4, "r_x": 0.4, "b_x": 0.4, "cl_x": 0.4, "cr_x": 0.4,
                        "l_y": 0.5, "r_y": 0.5,
                        "b_y": pytest.approx(0.225), "cl_y": pytest.approx(0.225),
                        "cr_y": pytest.approx(0.225)}
    rng = np.random.default_rng(0)
    prev = world.reset(seed=3)
    steps: dict[str, list[float]] = {k: [] for k in prev}
    learner = ModelLearner(world.variables, Params())
    for t in range(5000):
        obs = world.step({"u": float(rng.choice([-1.0, 0.0, 1.0]))})
        learner.observe(t, {"u": 0.0, **obs}, discontinuity=world.discontinuity)
        if not world.discontinuity:
            for k in obs:
                steps[k].append(abs(obs[k] - prev[k]))
        prev = obs
    for name in ("b_x", "cl_x", "cr_x"):
        assert np.median(steps[name]) == pytest.approx(0.4)  # every tick but a bounce
        assert max(steps[name]) == pytest.approx(0.4)
    for name in ("l_y", "r_y"):
        assert set(np.round(steps[name], 9)) == {0.0, 0.5}
    assert np.mean(steps["b_y"]) == pytest.approx(0.225, abs=0.02)
    b_y = learner.table.index("b_y")
    assert learner.perception.resolution(b_y) == pytest.approx(0.225)
    assert 0.5 * learner.perception.bin_size(b_y) != pytest.approx(0.225, abs=1e-4)
    lb, ub = learner._fit_resolution(b_y, 3.5, 3.6)  # type: ignore[misc]
    assert (lb, ub) == (pytest.approx(3.4375), pytest.approx(3.6625)) and ub - lb >= 0.225
