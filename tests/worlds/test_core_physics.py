"""Physics of the core world that the agent's landmarks depend on (Table 8.1, §7.1)."""

from __future__ import annotations

import numpy as np
import pytest

from worlds import make
from worlds.core.world import CoreWorld


@pytest.fixture
def world() -> CoreWorld:
    w = make("core")
    assert isinstance(w, CoreWorld)
    w.reset(seed=0)
    return w


def _clear_table(world: CoreWorld) -> None:
    """Hand in the middle, block far away in a corner so the hand touches nothing."""
    world.set_hand(0.0, 0.5, 12.75)
    world.place_block(np.random.default_rng(0), x=-3.2, y=-1.9, width=1.0)


def _drift(world: CoreWorld, motor: dict[str, float], steps: int, axis: str) -> float:
    start = world._observe()[axis]
    for _ in range(steps):
        obs = world.step(motor)
    return obs[axis] - start


@pytest.mark.parametrize(("motor", "axis"), [("u_x", "h_x"), ("u_y", "h_y")])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_290_does_not_move_the_hand_and_310_does(
    world: CoreWorld, motor: str, axis: str, sign: float
) -> None:
    _clear_table(world)
    assert abs(_drift(world, {motor: sign * 290.0}, 40, axis)) < 0.005
    _clear_table(world)
    moved = sign * _drift(world, {motor: sign * 310.0}, 40, axis)
    assert moved > 0.1


@pytest.mark.parametrize(("motor", "axis"), [("u_x", "h_x"), ("u_y", "h_y"), ("u_z", "h_z")])
def test_moderate_force_moves_the_hand_clearly_per_step(
    world: CoreWorld, motor: str, axis: str
) -> None:
    _clear_table(world)
    world.set_hand(0.0, 0.5, 11.2)  # room to move up to the limits
    force = 950.0 if motor == "u_z" else 400.0
    _drift(world, {motor: force}, 4, axis)
    per_step = _drift(world, {motor: force}, 2, axis) / 2
    assert per_step > 0.15  # well outside the agent's zero band of ±0.1 per step


def test_lowering_needs_less_force_than_lifting(world: CoreWorld) -> None:
    _clear_table(world)
    assert abs(_drift(world, {}, 40, "h_z")) < 0.005  # the arm holds its own weight
    _clear_table(world)
    assert _drift(world, {"u_z": -100.0}, 10, "h_z") < -0.2  # lowering: small force
    _clear_table(world)
    assert abs(_drift(world, {"u_z": 310.0}, 40, "h_z")) < 0.005  # enough in x, not up
    _clear_table(world)
    assert abs(_drift(world, {"u_z": 500.0}, 40, "h_z")) < 0.005
    _clear_table(world)
    assert _drift(world, {"u_z": 650.0}, 10, "h_z") > 0.2


def test_block_moves_when_the_hands_side_hits_it(world: CoreWorld) -> None:
    rng = np.random.default_rng(0)
    world.set_hand(-2.0, 0.0, 11.0)
    world.place_block(rng, x=1.0, y=0.0, width=1.5)
    t_l = [world._observe()["T_L"]]
    x_lr = []
    for _ in range(12):
        obs = world.step({"u_x": 450.0})
        t_l.append(obs["T_L"])
        x_lr.append(obs["x_LR"])
    steps = np.diff(t_l)
    assert steps.max() > 0.1  # T_L.dot = [+]: the block moved left, visibly per step
    assert t_l[-1] - t_l[0] > 1.0
    assert min(abs(v) for v in x_lr) < 0.2  # pushed at x_LR ≈ 0 (Table 8.1's landmark)
    assert abs(world.block_position()[1]) < 0.2  # pushed straight
    assert obs["z_F"] < 10.8  # slides, is not thrown up


def test_grasp_and_let_go_follow_the_stated_probabilities(world: CoreWorld) -> None:
    rng = np.random.default_rng(1)
    world.place_block(rng, x=0.0, y=0.5, width=2.0)
    grasped_steps = releases = moves = 0
    previous_t = 0.0
    for step in range(3000):
        if step == 0 or world.block_replaced:
            bx, by, _ = world.block_position()
            world.set_hand(bx, by, 10.5 + world.width + 0.3)  # over the block's centre
            previous_t = 0.0
        obs = world.step({"u_z": -150.0, "u_UG": 0.0})
        if previous_t == 1.0:
            grasped_steps += 1
            if obs["T"] == 0.0:
                releases += 1
                moves += world.block_replaced
        previous_t = obs["T"]
    assert grasped_steps > 1500
    assert 0.07 < releases / grasped_steps < 0.13  # let go with probability 0.1 per step
    assert 0.35 < moves / releases < 0.65  # moved with probability 0.5 when let go


def test_grasp_needs_the_centres_within_1_5(world: CoreWorld) -> None:
    rng = np.random.default_rng(2)
    world.place_block(rng, x=0.0, y=0.5, width=3.0)
    world.set_hand(1.2, 0.5 + 1.2, 14.2)  # touching the top, 1.7 from the centre
    for _ in range(30):
        obs = world.step({"u_z": -150.0})
        assert obs["T"] == 0.0
    assert obs["z_BT"] < 0.05  # resting on the block's top


def test_ungrasp_motor_lets_go(world: CoreWorld) -> None:
    rng = np.random.default_rng(3)
    world.place_block(rng, x=0.0, y=0.5, width=2.0)
    world.set_hand(0.0, 0.5, 13.2)
    for _ in range(20):
        if world.step({"u_z": -150.0})["T"] == 1.0:
            break
    assert world.grasped
    assert world.step({"u_UG": 1.0})["T"] == 0.0


def test_bang_fires_when_the_block_reaches_the_floor_then_it_is_replaced(
    world: CoreWorld,
) -> None:
    rng = np.random.default_rng(4)
    world.set_hand(0.5, 0.0, 11.0)
    world.place_block(rng, x=2.6, y=0.0, width=1.0)
    bangs = []
    for _ in range(80):
        obs = world.step({"u_x": 600.0})
        if obs["bang"] == 1.0:
            bangs.append(obs)
            break
    assert bangs, "the block never hit the floor"
    assert bangs[0]["z_F"] < 0.3  # on the floor
    assert bangs[0]["T_L"] > 0.0  # went off the left edge
    obs = world.step({})
    assert world.block_replaced
    assert obs["bang"] == 0.0
    assert obs["z_F"] == pytest.approx(10.5, abs=0.05)  # a new block on the table


def test_block_out_of_reach_and_still_is_replaced(world: CoreWorld) -> None:
    rng = np.random.default_rng(5)
    world.place_block(rng, x=0.0, y=-4.6, width=1.0)  # on the table, behind the hand's reach
    world.set_hand(0.0, 2.0, 13.0)
    replaced_at = None
    for step in range(1, 20):
        world.step({})
        if world.block_replaced:
            replaced_at = step
            break
    assert replaced_at is not None
    assert replaced_at < 10
    assert world.block_position()[1] > -2.5


def test_floating_balls_move_and_the_contingent_ball_follows_the_hand() -> None:
    world = make("core:contingent:jump")
    world.reset(seed=0)
    world.set_hand(2.0, 2.0, 14.0)  # inside the jump band (13.75, 14.25)
    before = world.observation["f1_z"]
    obs = world.step({})
    assert obs["f1_z"] - before > 0.3


def test_same_seed_same_motors_same_observations() -> None:
    a, b = make("core:floating"), make("core:floating")
    rng_a, rng_b = np.random.default_rng(9), np.random.default_rng(9)
    assert a.reset(seed=7) == b.reset(seed=7)
    for _ in range(200):
        ma = {k: float(rng_a.uniform(-1000, 1000)) for k in ("u_x", "u_y", "u_z")}
        mb = {k: float(rng_b.uniform(-1000, 1000)) for k in ("u_x", "u_y", "u_z")}
        assert a.step(ma) == b.step(mb)
    assert a.reset(seed=8) != b.reset(seed=7)


def test_render_text_shows_table_block_and_hand(world: CoreWorld) -> None:
    text = world.render_text(60, 20)
    assert "." in text
    assert "#" in text
    assert "H" in text or "h" in text
    assert len(text.splitlines()) <= 20
