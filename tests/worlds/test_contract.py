"""The world contract, checked over every registered world and variant, and the registry."""

from __future__ import annotations

import math

import pytest

import worlds
from worlds import VarKind, check_world, make, registered


@pytest.mark.parametrize("spec", registered())
def test_check_world(spec: str) -> None:
    world = make(spec)
    try:
        check_world(world, steps=300, seed=0)
        assert world.name == spec
    finally:
        world.close()


def test_registry_lists_every_world_and_variant() -> None:
    specs = registered()
    for expected in (
        "core",
        "core:floating",
        "core:random1",
        "core:random2",
        "core:relevant1",
        "core:relevant2",
        "core:secondary:aligned",
        "core:secondary:unaligned",
        "core:contingent:rising",
        "core:contingent:jump",
        "core2d",
        "pong",
        "gym:Pendulum-v1",
        "gym:MountainCarContinuous-v0",
    ):
        assert expected in specs


def test_unknown_world_lists_registered_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown world 'nope'.*core.*pong"):
        make("nope")


def test_bad_variant_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="core has no variant 'flying'"):
        make("core:flying")
    with pytest.raises(ValueError, match="'aligned' or 'unaligned'"):
        make("core:secondary:sideways")


def test_import_path_spec() -> None:
    world = make("worlds.pong.world:PongWorld", random_paddles=True)
    assert world.name == "pong"
    assert world.random_paddles  # type: ignore[attr-defined]


def test_public_names() -> None:
    assert set(worlds.__all__) >= {
        "VarKind",
        "VariableSpec",
        "Goal",
        "Task",
        "World",
        "make",
        "register",
        "registered",
        "check_world",
    }
    assert VarKind.MOTOR == "motor"


@pytest.mark.parametrize("spec", ["core", "core2d", "pong"])
def test_bad_motor_input_raises_clear_errors(spec: str) -> None:
    world = make(spec)
    motor = world.variables[0]
    assert motor.kind is VarKind.MOTOR
    with pytest.raises(ValueError, match="unknown motor 'u_q'"):
        world.step({"u_q": 0.0})
    with pytest.raises(ValueError, match=rf"motor '{motor.name}' got nan"):
        world.step({motor.name: math.nan})
    with pytest.raises(ValueError, match=rf"motor '{motor.name}' got inf"):
        world.step({motor.name: math.inf})
    with pytest.raises(ValueError, match=rf"motor '{motor.name}' got 5000.0, outside its range"):
        world.step({motor.name: 5000.0})
    assert world.step_count == 0
    obs = world.step({})  # missing motors are 0
    assert world.step_count == 1
    assert set(obs) == set(world.available_names())


def test_motors_first_and_observations_exclude_motors() -> None:
    world = make("core")
    kinds = [v.kind for v in world.variables]
    assert kinds[:4] == [VarKind.MOTOR] * 4
    assert VarKind.MOTOR not in kinds[4:]
    obs = world.reset(seed=1)
    assert not {"u_x", "u_y", "u_z", "u_UG"} & set(obs)
    # Table 7.1: 4 motors, 14 magnitudes (each with a derivative on the agent side), T, bang.
    assert len(world.variables) == 20
    assert sum(v.kind is VarKind.MAGNITUDE for v in world.variables) == 14


def test_transfer_withholds_bang_and_z_f_until_the_given_step() -> None:
    world = make("core:transfer:5")
    obs = world.reset(seed=0)
    assert "bang" not in obs
    assert "z_F" not in obs
    for _ in range(4):
        obs = world.step({})
        assert "z_F" not in obs
    obs = world.step({})
    assert world.step_count == 5
    assert "z_F" in obs
    assert "bang" in obs
    spec = {v.name: v for v in world.variables}
    assert spec["z_F"].available_from == 5
    assert make("core:transfer").variables[-1].available_from in (0, 150_000)


def test_variant_variables() -> None:
    names = lambda spec: {v.name for v in make(spec).variables}  # noqa: E731
    core = names("core")
    assert names("core:floating") - core == {f"f{i}_{a}" for i in (1, 2) for a in "xyz"}
    assert names("core:random1") - names("core:floating") == {"r1", "r2", "r3"}
    assert names("core:random2") - names("core:random1") == {"r4", "r5", "r6"}
    assert names("core:relevant1") - core == {"y_TT", "x_LL", "b_TY", "b_LX", "h_TY", "h_LX"}
    assert names("core:relevant2") - names("core:relevant1") == {
        "y_BB",
        "x_RR",
        "b_BY",
        "b_RX",
        "h_BY",
        "h_RX",
    }
    secondary = names("core:secondary:aligned")
    assert core - secondary == {"z_F", "T_L", "T_R", "T_T", "bang"}
    assert secondary - core == {"x_BB", "y_BB", "z_BB", "m_BB"}
    assert core - names("core2d") == {"u_z", "u_UG", "h_z", "z_BT", "c_x", "c_y", "T", "bang"}
    pong = make("pong")
    assert dict(pong.agent_options) == {"k_fixed": 6, "nrp": True}
