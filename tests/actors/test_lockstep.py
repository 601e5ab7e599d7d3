"""Same knowledge everywhere: the synchronous loop and the actor placements in lockstep."""

from __future__ import annotations

import json

import pytest

import worlds
from qlap_runtime import agent_run
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.placements.launcher import run_embedded, run_processes
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext

STEPS = 3000
BASE = Params(babble_steps=1500, dbn_period=500, landmark_period=1000)


def sync_knowledge(world_spec: str, params: Params, seed: int) -> str:
    return agent_run.sync_knowledge(world_spec, STEPS, seed, params)


def context(tmp_path, world_spec: str, params: Params, seed: int, run_id: str) -> RunContext:
    world = worlds.make(world_spec)
    params = params_for_world(world, params)
    world.close()
    return RunContext(run_id, world_spec, STEPS, seed, params, out=tmp_path)


@pytest.mark.parametrize("lag", [0, 200])
def test_embedded_lockstep_equals_the_synchronous_loop(tmp_path, lag):
    params = BASE.replace(batch_lag=lag)
    expected = sync_knowledge("core2d", params, seed=3)
    summary = run_embedded(context(tmp_path, "core2d", params, 3, f"t-emb-{lag}"))
    got = (tmp_path / "knowledge.json").read_text()
    assert json.loads(got)["dbns"], "nothing was learned: the comparison would be empty"
    assert got == expected
    assert summary["steps"] == STEPS
    assert summary["rejected_messages"] == 0


def test_processes_lockstep_equals_the_synchronous_loop(tmp_path):
    params = BASE.replace(batch_lag=200)
    expected = sync_knowledge("core2d", params, seed=5)
    summary = run_processes(context(tmp_path, "core2d", params, 5, "t-proc"))
    assert (tmp_path / "knowledge.json").read_text() == expected
    assert summary["placement"] == "processes"
