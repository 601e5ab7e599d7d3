"""``World.scene()``: the bodies a 3D view (the recorder's foxglove.SceneUpdate) draws, checked
against the physics engines' own geometry, from the state and from an observation alone."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import worlds
from worlds.core2d.world import Core2DWorld

from .conftest import Babble


def _by_id(bodies: list[dict]) -> dict[str, dict]:
    ids = [b["id"] for b in bodies]
    assert len(ids) == len(set(ids))
    return {b["id"]: b for b in bodies}


@pytest.mark.parametrize("spec", ["core", "core:floating", "core:secondary:aligned"])
def test_core_scene_is_mujocos_geometry(spec: str, babble: Babble) -> None:
    world = worlds.make(spec)
    try:
        world.reset(seed=4)
        m, d = world.model, world.data
        checked = 0
        for t, obs in enumerate(babble(world, 400, seed=4)):
            if t % 40:
                continue
            world.sync_visuals()
            mujoco.mj_forward(m, d)
            scene = _by_id(world.scene())
            names = {"table", "hand", "block"} | {f"table_leg{i}" for i in range(1, 5)}
            if world.secondary:
                names.add("block2")
            if world.balls is not None:
                names |= {"ball1", "ball2"}
            assert set(scene) == names
            for name, body in scene.items():
                geom = name.replace("table_", "").replace("ball", "float")
                g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, geom)
                full = 2 * m.geom_size[g] if body["shape"] == "box" else [2 * m.geom_size[g][0]] * 3
                np.testing.assert_allclose(body["centre"], d.geom_xpos[g], atol=1e-9, err_msg=name)
                np.testing.assert_allclose(body["size"], full, atol=1e-9, err_msg=name)
                assert len(body["rgba"]) == 4
            assert scene["hand"]["size"] == (3.0, 3.0, 0.5)
            hx, hy, hz = world.hand_position()
            assert scene["hand"]["centre"] == (-hx, hy, hz)     # MuJoCo's x is the reference's −x
            # From the observation alone (a recorded sense): the same, but the unobservable block2.
            from_obs = _by_id(world.scene(dict(obs)))
            scene.pop("block2", None)
            assert from_obs.keys() == scene.keys()
            for name, body in scene.items():
                np.testing.assert_allclose(from_obs[name]["centre"], body["centre"], atol=1e-9)
                np.testing.assert_allclose(from_obs[name]["size"], body["size"], atol=1e-9)
            checked += 1
        assert checked == 10
    finally:
        world.close()


def test_core2d_scene_is_pymunks_geometry(babble: Babble) -> None:
    world = Core2DWorld()
    world.reset(seed=2)
    falls = 0
    for obs in babble(world, 3000, seed=2):
        scene = _by_id(world.scene())
        assert set(scene) == {"table", "hand", "block"}
        hx, hy = world.hand.position
        bx, by = world.block.position
        assert scene["hand"]["centre"] == pytest.approx((-hx, hy, 11.0), abs=1e-9)
        assert scene["hand"]["size"] == (3.0, 3.0, 0.5)
        w = world.width
        assert scene["block"]["centre"] == pytest.approx((-bx, by, world.z_f + w / 2), abs=1e-9)
        assert scene["block"]["size"] == pytest.approx((w, w, w), abs=1e-9)
        assert scene["table"]["size"] == (21.0, 10.0, 2.0)
        assert scene["table"]["centre"] == (6.5, -1.0, 9.5)
        assert world.scene(dict(obs)) == list(scene.values())
        falls += world.z_f < 10.5
    assert falls > 0, "no fall: the block's height was never checked off the table"
