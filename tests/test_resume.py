"""Exact resume (issue 13): a checkpoint carries the world's state (``world.json``), so that
``--resume`` of the checkpoint at step S run to T gives the uninterrupted run's knowledge.json
byte for byte (docs/decisions.md 41)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import worlds
from qlap_runtime.agent_run import run_agent
from qlap_runtime.qlap import Params
from qlap_runtime.qlap.checkpoint import (
    CheckpointError,
    load_agent,
    load_world_state,
    restore_world,
)
from tests.test_cli_errors import assert_one_line, qlap


def _resume(ckpt: Path, spec: str, steps: int, out: Path, params: Params) -> bytes:
    world = worlds.make(spec)
    restore_world(world, load_world_state(ckpt), ckpt)
    run_agent(world, steps, 0, out, params=params, agent=load_agent(ckpt), restored=True,
              checkpoint_every=1000)
    return (out / "knowledge.json").read_bytes()


#: Batches every 500 steps, babbling until 1,500, k fixed and 15 data points (as
#: tests/actors/test_faults.py): DBNs, landmarks and plans within 3,000 steps.
FAST = {"dbn_period": 500, "landmark_period": 1000, "babble_steps": 1500, "k_fixed": 5,
        "min_data_points": 15}


@pytest.mark.parametrize(("spec", "lag"), [("core", 0), ("core2d", 200), ("pong", 0)])
def test_resume_of_any_checkpoint_equals_the_uninterrupted_run(tmp_path, spec, lag) -> None:
    """3,000 steps, checkpoints every 1,000; the run resumed from step-0001000 and from
    step-0002000 (seed 0 given: the agent's and the world's generators come from the
    checkpoint) ends with knowledge.json byte-identical to the uninterrupted run's."""
    params = Params(batch_lag=lag, **FAST)
    full = tmp_path / "full"
    run_agent(worlds.make(spec), 3000, 5, full, params=params, checkpoint_every=1000)
    expected = (full / "knowledge.json").read_bytes()
    assert json.loads(expected)["dbns"], "nothing learned: the comparison would be empty"
    for s in (1000, 2000):
        ckpt = full / "checkpoints" / f"step-{s:07d}"
        assert (ckpt / "world.json").is_file()
        assert _resume(ckpt, spec, 3000 - s, tmp_path / f"from{s}", params) == expected
    assert (tmp_path / "from2000" / "checkpoints" / "final" / "world.json").exists()


def test_without_the_world_state_the_resumed_run_differs(tmp_path) -> None:
    """The failure this fixes: the world started again from reset(seed)."""
    params = Params(**FAST)
    full = tmp_path / "full"
    run_agent(worlds.make("core2d"), 3000, 5, full, params=params, checkpoint_every=1000)
    ckpt = full / "checkpoints" / "step-0001000"
    run_agent(worlds.make("core2d"), 2000, 5, tmp_path / "reset", params=params,
              agent=load_agent(ckpt), checkpoint_every=1000)
    assert (tmp_path / "reset" / "knowledge.json").read_bytes() \
        != (full / "knowledge.json").read_bytes()


def test_qlap_run_resume_restores_the_world_and_refuses_a_corrupt_state(capsys,
                                                                         tmp_path) -> None:
    run = tmp_path / "run"
    base = ("run", "--headless", "--quiet", "--placement", "sync", "--world", "core2d")
    code, _, err = qlap(capsys, *base, "--steps", "600", "--out", str(run))
    assert code == 0, err
    final = run / "checkpoints" / "final"
    code, _, err = qlap(capsys, *base, "--steps", "100", "--resume", str(final),
                        "--out", str(tmp_path / "ok"))
    assert code == 0 and "no world state" not in err
    # --steps counts the steps after the checkpoint's (its --help says so): 600 + 100
    ok = json.loads((tmp_path / "ok" / "knowledge.json").read_text())
    assert ok["step"] == 699
    state = json.loads((final / "world.json").read_text())
    corrupt = [
        ("{not json", "core2d", "corrupt world state"),
        # another world: refused by the agent's own variables before world.json is read
        (json.dumps(state), "core", "learned in world 'core2d', not --world 'core'"),
        (json.dumps({**state, "replay": {**state["replay"], "n_motors": 3}}), "core2d",
         "3 motors"),
        (json.dumps({**state, "observation": {"h_x": 1.0}}), "core2d", "does not reach the saved"),
    ]
    for i, (text, world, fragment) in enumerate(corrupt):
        (final / "world.json").write_text(text)
        argv = [a if a != "core2d" else world for a in base]
        code, _, err = qlap(capsys, *argv, "--steps", "100", "--resume", str(final),
                            "--out", str(tmp_path / f"bad{i}"))
        assert_one_line(code, err, "--resume", fragment,
                        *(["world.json"] if world == "core2d" else []))
    (final / "world.json").unlink()                 # an older checkpoint: said, not fatal
    code, _, err = qlap(capsys, *base, "--steps", "100", "--resume", str(final),
                        "--out", str(tmp_path / "old"))
    assert code == 0 and "holds no world state" in err
    # Its variables edited: not "learned in world 'core2d', not --world 'core2d'".
    meta = json.loads((final / "learner.json").read_text())
    meta["variables"][0]["name"] = "zz"
    (final / "learner.json").write_text(json.dumps(meta))
    code, _, err = qlap(capsys, *base, "--steps", "100", "--resume", str(final),
                        "--out", str(tmp_path / "edited"))
    assert_one_line(code, err, "its variables are not those of world 'core2d' (which has no zz)",
                    "a damaged checkpoint")


def test_load_world_state_names_the_file(tmp_path) -> None:
    (tmp_path / "world.json").write_text("[1, 2]")
    with pytest.raises(CheckpointError, match="world.json: not a qlap-world-state"):
        load_world_state(tmp_path)


def test_a_missing_stats_part_names_the_realtime_clock(tmp_path):
    """The refusal of a checkpoint without pair statistics says why it has none: a run under
    the realtime clock keeps none (the usual case), else the part was lost."""
    import json

    from qlap_runtime.placements.resume import why_no_stats

    ckpt = tmp_path / "run" / "checkpoints" / "final"
    ckpt.mkdir(parents=True)
    assert why_no_stats(ckpt) == "an actor placement's checkpoint without its stats part"
    (tmp_path / "run" / "summary.json").write_text(json.dumps({"clock": "realtime"}))
    assert why_no_stats(ckpt) == "a run under --clock realtime, whose learners keep none"
    (tmp_path / "run" / "summary.json").write_text("[")
    assert why_no_stats(ckpt) == "an actor placement's checkpoint without its stats part"
