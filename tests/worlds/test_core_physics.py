"""Physics of the core world that the agent's landmarks depend on (Table 8.1, §7.1)."""

from __future__ import annotations

import numpy as np
import pytest

from worlds import DOT_BAND, make
from worlds.base import VarKind
from worlds.core import world as core
from worlds.core.world import CoreWorld

from .conftest import Babble


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
    world.step({})
    previous = world.observation[axis]
    for _ in range(40):
        current = world.step({motor: sign * 290.0})[axis]
        # Still, as the agent sees it: within the per-second zero band on every step.
        assert abs(current - previous) / world.step_seconds <= DOT_BAND
        previous = current
    _clear_table(world)
    moved = sign * _drift(world, {motor: sign * 310.0}, 40, axis)
    assert moved > 0.1  # (310 − 300) / 75 = 0.13 units/s: ḣ → [±] outside the band


@pytest.mark.parametrize("force", [400.0, 700.0, 1000.0, -400.0, -1000.0])
@pytest.mark.parametrize(("motor", "axis"), [("u_x", "h_x"), ("u_y", "h_y")])
def test_hand_speed_is_the_references(
    world: CoreWorld, motor: str, axis: str, force: float
) -> None:
    """(|u| − 300) / 75 units/s: 0.47 units per step at |u| = 1000 (Table 8.9: 0.44–0.48)."""
    _clear_table(world)
    start = -2.5 if force > 0 else 2.5
    world.set_hand(start if axis == "h_x" else 0.0, start + 0.5 if axis == "h_y" else 0.5, 12.75)
    _drift(world, {motor: force}, 4, axis)
    per_step = _drift(world, {motor: force}, 1, axis)
    expected = np.sign(force) * (abs(force) - 300.0) / 75.0 * world.step_seconds
    assert per_step == pytest.approx(expected, rel=0.02)
    if abs(force) == 1000.0:
        assert 0.44 < abs(per_step) < 0.48


def test_hand_speed_up_and_down(world: CoreWorld) -> None:
    """Up: (u_z − 550) / 75 units/s; down: (|u_z| − 50) / 75, at most 700 / 75."""
    _clear_table(world)
    world.set_hand(0.0, 0.5, 11.0)
    _drift(world, {"u_z": 950.0}, 3, "h_z")
    assert _drift(world, {"u_z": 950.0}, 1, "h_z") == pytest.approx(400 / 75 * 0.05, rel=0.02)
    world.set_hand(0.0, 0.5, 14.5)
    _drift(world, {"u_z": -1000.0}, 3, "h_z")
    assert _drift(world, {"u_z": -1000.0}, 1, "h_z") == pytest.approx(-700 / 75 * 0.05, rel=0.02)


@pytest.mark.parametrize(
    ("motor", "axis", "limit"),
    [
        ("u_x", "h_x", 2.5),
        ("u_x", "h_x", -2.5),
        ("u_y", "h_y", 3.0),
        ("u_y", "h_y", -2.0),
        ("u_z", "h_z", 14.5),
        ("u_z", "h_z", 11.0),
    ],
)
def test_hand_rests_exactly_at_its_limits(
    world: CoreWorld, motor: str, axis: str, limit: float
) -> None:
    """Hard stops: pushed at full force against a limit, the hand stays on it, still (the
    soft limit used to spring back over several steps: a false ḣ → [−] after every hit)."""
    _clear_table(world)
    force = 1000.0 if limit == {"h_x": 2.5, "h_y": 3.0, "h_z": 14.5}[axis] else -1000.0
    values = [world.step({motor: force})[axis] for _ in range(30)]
    assert values[-1] == limit
    arrived = values.index(limit)
    assert arrived < 15
    assert all(v == limit for v in values[arrived:])


def _push(
    world: CoreWorld, axis: str, force: float, steps: int
) -> tuple[float, float, list[float]]:
    """The hand pushes a 1.5-wide block from the right (axis x, moving left) or from behind
    (axis y, moving forward) for ``steps`` steps after touching it, then lets go. Returns the
    hand's travel while pushing, the block's displacement when it has stopped, and z_F at every
    step."""
    rng = np.random.default_rng(0)
    if axis == "x":
        world.place_block(rng, x=0.5, y=0.0, width=1.5)
        world.set_hand(-2.5, 0.0, 11.0)
        motor, gap, i = "u_x", "x_LR", 0
    else:
        world.place_block(rng, x=0.0, y=0.5, width=1.5)
        world.set_hand(0.0, -2.0, 11.0)
        motor, gap, i = "u_y", "y_TB", 1
    z_f = [world.step({})["z_F"]]
    obs = world.observation
    while obs[gap] < -0.02:
        obs = world.step({motor: force})
        z_f.append(obs["z_F"])
    hand0, block0 = obs[f"h_{axis}"], world.block_position()[i]
    for _ in range(steps):
        obs = world.step({motor: force})
        z_f.append(obs["z_F"])
        assert not world.discontinuity
    hand1 = obs[f"h_{axis}"]
    for _ in range(20):
        z_f.append(world.step({})["z_F"])
        assert not world.discontinuity
    return hand1 - hand0, world.block_position()[i] - block0, z_f


@pytest.mark.parametrize("axis", ["x", "y"])
@pytest.mark.parametrize(("force", "steps"), [(450.0, 6), (700.0, 4), (1000.0, 3)])
def test_a_push_moves_the_block_about_as_far_as_the_hand_travels(
    world: CoreWorld, axis: str, force: float, steps: int
) -> None:
    """§7.1's scale: the block slides a little after the hand stops (v²/2μg ≲ 0.5 at the hand's
    top speed); it does not skate off the table (gravity 9.81 against a 10.5-high table made a
    3-step push at |u| ≥ 600 slide it 13.9 units), and it never tips (z_F stays 10.5)."""
    hand, block, z_f = _push(world, axis, force, steps)
    friction = 0.6 * 0.25 * 140.0  # the block's sliding friction slows the hand a little
    assert hand == pytest.approx((force - 300.0 - friction) / 75.0 * 0.05 * steps, rel=0.1)
    assert hand - 0.02 < block < hand + 0.6
    assert max(z_f) - min(z_f) < 1e-3
    assert min(z_f) == pytest.approx(10.5, abs=1e-3)


def test_table_extent(world: CoreWorld) -> None:
    """x ∈ [−17, 4], y ∈ [−6, 4]: T_R − T_L = 21 (the reference's T_R landmarks at 12.3–21.1)."""
    assert world.table == (-17.0, 4.0, -6.0, 4.0)
    obs = world.observation
    assert obs["T_R"] - obs["T_L"] == pytest.approx(21.0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        world.place_block(rng)
        obs = world._observe()
        assert 14.0 <= obs["T_R"] <= 20.0  # placed within reach: x ∈ [−3, 3]
        assert obs["T_L"] <= -1.0  # at least 1 from the edges it can fall off
        assert obs["T_T"] <= -1.0


@pytest.mark.parametrize(("motor", "edge"), [("u_x", "T_L"), ("u_y", "T_T")])
def test_block_falls_when_its_centre_passes_the_left_or_far_edge(
    world: CoreWorld, motor: str, edge: str
) -> None:
    rng = np.random.default_rng(4)
    if motor == "u_x":
        world.place_block(rng, x=2.2, y=0.0, width=1.0)
        world.set_hand(0.0, 0.0, 11.0)
    else:
        world.place_block(rng, x=0.0, y=2.6, width=1.0)
        world.set_hand(0.0, 0.5, 11.0)
    for _ in range(80):
        obs = world.step({motor: 700.0})
        if obs[edge] < 0.0:
            assert obs["z_F"] == pytest.approx(10.5, abs=1e-3)  # on the table until then
        if obs["bang"] == 1.0:
            break
    assert obs["bang"] == 1.0
    assert obs[edge] > 0.0


def test_block_pushed_right_stays_on_the_table(world: CoreWorld) -> None:
    """The table reaches far to the right: the block goes out of reach and is replaced, it
    does not fall (the reference: "the block rarely goes off the table to the right")."""
    rng = np.random.default_rng(5)
    world.place_block(rng, x=-1.0, y=0.0, width=1.0)
    world.set_hand(2.5, 0.0, 11.0)
    for _ in range(60):
        obs = world.step({"u_x": -1000.0})
        assert obs["bang"] == 0.0
        if world.block_replaced:
            break
    assert world.block_replaced


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


def test_babbling_hand_is_not_always_at_a_limit(babble: Babble) -> None:
    """At the reference's speed the babbling hand (Appendix E: each motor holds a random value
    for 0–40 steps) sits within 0.05 of an x or y limit on about 82 % of steps (seed 0, 5,000
    steps); at the earlier 0.6 units per step it was 94 %."""
    world = make("core")
    world.reset(seed=0)
    low, high = core.HAND_LOW, core.HAND_HIGH
    at_limit = 0
    for obs in babble(world, 5000, 0):
        x, y = obs["h_x"], obs["h_y"]
        at_limit += min(x - low[0], high[0] - x, y - low[1], high[1] - y) < 0.05
    assert at_limit / 5000 < 0.9


def test_resolution_is_the_hands_mean_step_in_one_tick(babble: Babble) -> None:
    """Every position-like magnitude declares the resolution 0.16 (docs/decisions.md 114): the
    mean step of the hand and of the hand–block distances in one tick while they move, under
    Appendix E's babbling (seed 0, 5,000 steps: 0.15–0.19); a landmark value narrower than
    that is one the hand steps over."""
    world = make("core")
    prev = world.reset(seed=0)
    declared = {v.name: v.resolution for v in world.variables if v.kind is VarKind.MAGNITUDE}
    assert set(declared.values()) == {0.16} and core.RESOLUTION == 0.16
    names = ("h_x", "h_y", "h_z", "x_RL", "x_LR", "y_TB", "y_BT", "c_x", "c_y")
    steps: dict[str, list[float]] = {n: [] for n in names}
    for obs in babble(world, 5000, 0):
        if not world.discontinuity:
            for n in names:
                if (d := abs(obs[n] - prev[n])) > 1e-3:
                    steps[n].append(d)
        prev = obs
    means = {n: float(np.mean(s)) for n, s in steps.items()}
    assert all(0.14 <= m <= 0.20 for m in means.values()), means
    assert float(np.mean(list(means.values()))) == pytest.approx(0.16, abs=0.02)
