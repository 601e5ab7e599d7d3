"""A world's NaN, ±inf and huge values, and a world that raises (issue 13, item 4)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import worlds
from qlap_runtime.agent_run import WorldFailed, knowledge_json, params_for_world, run_agent
from qlap_runtime.placements.launcher import run_embedded, run_processes
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext
from tests.actors import badworld

ROOT = Path(__file__).resolve().parents[2]
BAD = "tests.actors.badworld:bad_values"
RAISING = "tests.actors.badworld:raising"
STEPS = 3000
PARAMS = Params(babble_steps=1500, dbn_period=500, landmark_period=1000)


def params_of(spec: str) -> Params:
    w = worlds.make(spec)
    try:
        return params_for_world(w, PARAMS)
    finally:
        w.close()


@pytest.fixture(scope="module")
def sync_run():
    world = worlds.make(BAD)
    try:
        agent, summary = run_agent(world, STEPS, 3, params=PARAMS)
    finally:
        world.close()
    return knowledge_json(agent), summary


def test_sync_loop_rejects_nan_inf_and_huge_values(sync_run):
    knowledge, summary = sync_run
    assert json.loads(knowledge)["dbns"], "nothing learned: the comparison would be empty"
    assert summary["rejected_observations"] == len(badworld.BAD)
    assert [e.split(":")[0] for e in summary["rejected_examples"]] == \
        [f"step {t}" for t in sorted(badworld.BAD)]
    assert "beyond" in summary["rejected_examples"][1]          # 1e308: huge, not a crash


@pytest.mark.parametrize("placement", ["embedded", "processes"])
def test_actor_placements_skip_the_same_steps(tmp_path, sync_run, placement):
    knowledge, summary = sync_run
    ctx = RunContext(f"t-badworld-{placement}", BAD, STEPS, 3, params_of(BAD), out=tmp_path)
    run = run_embedded if placement == "embedded" else run_processes
    got_summary = run(ctx)
    assert (tmp_path / "knowledge.json").read_text() == knowledge
    assert got_summary["steps"] == STEPS
    # The world counts the numbers it sends as out of range; a name or a value that is not a
    # number is the perception actor's to reject (and name), as the sync loop's perception.
    numbers = [v for v in badworld.BAD.values() if isinstance(v, float)]
    assert got_summary["actors"]["world"]["rejected_senses"] == len(numbers) == 5
    assert got_summary["actors"]["perception"]["rejected_observations"] == len(badworld.BAD)
    assert got_summary["rejected_observations"] == summary["rejected_observations"]
    assert got_summary["rejected_examples"] == summary["rejected_examples"]   # same reasons


def outputs_written(out) -> dict:
    assert json.loads((out / "knowledge.json").read_text())["k"] is not None
    summary = json.loads((out / "summary.json").read_text())
    assert (out / "checkpoints" / "final").exists()
    return summary


def test_sync_world_exception_keeps_what_was_learned(tmp_path):
    world = worlds.make(RAISING)
    with pytest.raises(WorldFailed) as info:
        run_agent(world, 1200, 4, out=tmp_path, params=PARAMS)
    world.close()
    assert info.value.step == badworld.RAISE_AT - 1
    summary = outputs_written(tmp_path)
    assert summary["steps"] == badworld.RAISE_AT
    assert "failed at step" in summary["world_error"]


def test_embedded_world_exception_keeps_what_was_learned(tmp_path):
    ctx = RunContext("t-raising-emb", RAISING, 1200, 4, params_of(RAISING), out=tmp_path)
    with pytest.raises(BaseExceptionGroup) as info:
        run_embedded(ctx)
    assert info.value.subgroup(WorldFailed) is not None
    summary = outputs_written(tmp_path)
    assert summary["steps"] == badworld.RAISE_AT
    assert "failed at step" in summary["world_error"]
    # The same knowledge as the synchronous loop up to the failure.
    world = worlds.make(RAISING)
    with pytest.raises(WorldFailed):
        run_agent(world, 1200, 4, out=tmp_path / "sync", params=PARAMS)
    world.close()
    assert (tmp_path / "knowledge.json").read_text() == \
        (tmp_path / "sync" / "knowledge.json").read_text()


def test_ui_world_exception_keeps_what_was_learned(tmp_path):
    """The terminal UI's agent thread ends a broken world's run as the synchronous loop does:
    the outputs written, the same knowledge, and the failure shown (not a dead thread)."""
    from tests.local_driver import finished_driver

    world = worlds.make(RAISING)
    try:
        with finished_driver(world, seed=4, params=params_of(RAISING), steps=1200,
                             out=tmp_path / "ui", world_spec=RAISING) as d:
            assert d.finished and isinstance(d.error, WorldFailed)
            assert d.error.step == badworld.RAISE_AT - 1
            assert "failed at step" in d.runner.message
    finally:
        world.close()
    summary = outputs_written(tmp_path / "ui")
    assert summary["steps"] == badworld.RAISE_AT and "failed at step" in summary["world_error"]
    world = worlds.make(RAISING)
    with pytest.raises(WorldFailed):
        run_agent(world, 1200, 4, out=tmp_path / "sync", params=PARAMS)
    world.close()
    assert (tmp_path / "ui" / "knowledge.json").read_text() == \
        (tmp_path / "sync" / "knowledge.json").read_text()


@pytest.mark.parametrize("placement", ["sync", "embedded"])
def test_cli_world_exception_is_one_line(tmp_path, placement):
    out = tmp_path / "run"
    # The installed command (python -m qlap_runtime.cli would make a second CliError class).
    qlap = str(Path(sys.executable).parent / "qlap")
    r = subprocess.run([qlap, "run", "--world", RAISING,
                        "--steps", "1200", "--seed", "4", "--out", str(out), "--quiet",
                        "--placement", placement], capture_output=True, text=True,
                       timeout=300, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("run ")]
    assert len(lines) == 1, r.stderr
    assert "failed at step 899" in lines[0] and "Traceback" not in r.stderr
    outputs_written(out)
