"""Evaluation tasks (§7.2), the random baseline, and the PNG snapshot."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from worlds import Goal, make
from worlds.check import random_motor
from worlds.evaluate import run_random_trials, run_trials
from worlds.snapshot import main_snapshot, write_png


def test_core_tasks_and_goals() -> None:
    world = make("core")
    assert set(world.tasks) == {"move_block", "hit_floor", "pickup"}
    rng = np.random.default_rng(0)
    goals = set()
    for _ in range(30):
        obs = world.tasks["move_block"].setup(world, rng)
        goals.add(world.tasks["move_block"].goal(world, obs))
    assert goals <= {Goal("T_L.dot", "+"), Goal("T_R.dot", "-"), Goal("T_T.dot", "+")}
    assert len(goals) == 3
    assert world.tasks["hit_floor"].goal(world, obs) == Goal("bang", "true")
    assert world.tasks["pickup"].goal(world, obs) == Goal("T", "true")
    assert set(make("core:secondary:aligned").tasks) == {"pickup", "hit_secondary"}
    contingent = make("core:contingent:rising").tasks["contingent_up"]
    assert contingent.step_cost == -0.1
    assert contingent.hold_motors_at_zero_without_plan
    assert make("pong").tasks["pong_volley"].goal(make("pong"), {}).variable == "b_x.dot"


def test_task_trial_setup_places_block_within_reach() -> None:
    world = make("core")
    rng = np.random.default_rng(1)
    for _ in range(20):
        obs = world.tasks["pickup"].setup(world, rng)
        assert world.step_count == 0
        assert obs["z_F"] == pytest.approx(10.5, abs=0.01)
        assert -7.0 <= obs["T_L"] <= -1.0  # x ∈ [−3, 3], at least 1 from the left edge
        assert -6.0 <= obs["T_T"] <= -1.0  # y ∈ [−2, 3], at least 1 from the far edge
        assert not world.block_out_of_reach  # type: ignore[attr-defined]
        assert world.discontinuity


@pytest.mark.parametrize(
    ("spec", "task"),
    [
        ("core", "move_block"),
        ("core", "hit_floor"),
        ("core", "pickup"),
        ("core:secondary:aligned", "hit_secondary"),
        ("core:contingent:jump", "contingent_up"),
        ("core2d", "move_block"),
        ("pong", "pong_volley"),
    ],
)
def test_random_trials_report(spec: str, task: str) -> None:
    world = make(spec)
    result = run_random_trials(world, task, n_trials=3, seed=0)
    assert result["n_trials"] == 3
    assert len(result["rewards"]) == 3
    t = world.tasks[task]
    for reward in result["rewards"]:
        assert t.step_cost * t.max_steps - 1e-9 <= reward
        assert reward <= t.success_reward * (1 if t.episodic else t.max_steps)
    again = run_random_trials(world, task, n_trials=3, seed=0)
    assert again["rewards"] == result["rewards"]


def test_trials_are_counted_by_the_goal_they_started_with() -> None:
    """move_block draws left, right or forward per trial (§7.2.2 footnote 2): ``by_goal``
    splits the counts by that first goal and adds up to the totals; the 100 trials of seed 0
    make 36 left, 42 right and 18 forward, whatever the policy."""
    world = make("core")
    res = run_random_trials(world, "move_block", n_trials=100, seed=0)
    goals = res["by_goal"]
    assert {k: g["trials"] for k, g in goals.items()} == \
        {"T_L.dot=+": 36, "T_R.dot=-": 42, "T_T.dot=+": 22}
    for key in ("successes", "failures", "timeouts"):
        assert sum(g[key] for g in goals.values()) == res[key]
    assert sum(g["mean_reward"] * g["trials"] for g in goals.values()) == \
        pytest.approx(sum(res["rewards"]))
    one = run_random_trials(world, "hit_floor", n_trials=3, seed=0)["by_goal"]
    assert list(one) == ["bang=true"] and one["bang=true"]["trials"] == 3


def test_every_policy_meets_the_same_set_ups() -> None:
    """The set-ups draw from the trial seed alone, the policy from a stream of its own: a
    policy that draws every step (random motors) and one that draws nothing (still) see the
    same hands, blocks and goals, so a baseline is compared with the agent trial by trial."""
    world = make("core")
    seen: dict[str, list] = {"random": [], "still": []}

    def recorder(name: str, draw: bool):
        def policy(w, obs, goal, rng):
            if w.step_count == 0:
                seen[name].append((goal, round(obs["h_x"], 9), round(obs["T_L"], 9)))
            return random_motor(w, rng) if draw else dict.fromkeys(w.motor_names, 0.0)
        return policy

    run_trials(world, "move_block", 8, 5, recorder("random", True))
    run_trials(world, "move_block", 8, 5, recorder("still", False))
    assert len(seen["random"]) == 8 and seen["random"] == seen["still"]


def test_unknown_task() -> None:
    with pytest.raises(ValueError, match="no task 'fly'") as err:
        run_random_trials(make("core"), "fly", 1, 0)
    assert str(err.value) == ("core has no task 'fly'; its tasks: hit_floor, move_block, pickup "
                              "(qlap worlds lists every world's tasks; choose the world with "
                              "--world)")


def test_write_png(tmp_path: Path) -> None:
    image = np.zeros((4, 5, 3), dtype=np.uint8)
    image[1, 2] = (255, 0, 0)
    write_png(tmp_path / "a.png", image)
    assert (tmp_path / "a.png").read_bytes().startswith(b"\x89PNG\r\n\x1a\n")


def _offscreen_gl() -> bool:
    import ctypes.util

    import worlds.core  # noqa: F401 - sets MUJOCO_GL=osmesa without a display

    if os.environ.get("MUJOCO_GL") == "osmesa":
        return ctypes.util.find_library("OSMesa") is not None
    return bool(os.environ.get("DISPLAY") or os.environ.get("MUJOCO_GL") == "egl")


@pytest.mark.skipif(
    not _offscreen_gl(), reason="no offscreen GL: install libosmesa6 (MUJOCO_GL=osmesa)"
)
@pytest.mark.parametrize("spec", ["core", "core:secondary:aligned"])
def test_snapshot_png(tmp_path: Path, spec: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "scene.png"
    assert (
        main_snapshot(
            ["--world", spec, "--out", str(out), "--seed", "1", "--width", "160", "--height", "120"]
        )
        == 0
    )
    data = out.read_bytes()
    assert data.startswith(b"\x89PNG")
    assert len(data) > 2000  # not a blank picture
    assert str(out) in capsys.readouterr().out


def test_snapshot_rejects_non_mujoco_worlds(tmp_path: Path) -> None:
    assert main_snapshot(["--world", "pong", "--out", str(tmp_path / "p.png")]) == 2


def test_contingent_ball_does_not_rise_by_itself_in_evaluation() -> None:
    """§7.9.1: during evaluation the ball does not bounce up "without the agent having to do
    anything" — at the per-second zero band even a bounce at restitution 0.1 would read as
    ḟ_z → [+]; with the hand rising it does rise."""
    world = make("core:contingent:rising")
    task = world.tasks["contingent_up"]
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs = task.setup(world, rng)
        world.set_hand(0.0, 0.5, 11.0)  # below the jump band, still
        for _ in range(300):
            obs = world.step({})
            assert not task.is_success(world, obs)
        for _ in range(20):
            obs = world.step({"u_z": 1000.0})
            if task.is_success(world, obs):
                break
        assert task.is_success(world, obs)
