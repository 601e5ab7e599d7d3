"""Same knowledge everywhere: the synchronous loop, the actor placements in lockstep and the
terminal UI's local runner."""

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


def run_local(ctx: RunContext) -> dict:
    """The terminal UI's local runner (``tui/driver.py``: the agent in a thread, obeying the
    same runner contract as the executor) over the run, writing its outputs to ``ctx.out``."""
    from tests.local_driver import finished_driver

    world = worlds.make(ctx.world)
    try:
        with finished_driver(world, timeout_s=600, seed=ctx.seed, params=ctx.params,
                             steps=ctx.steps, out=ctx.out, run_id=ctx.run_id,
                             world_spec=ctx.world) as d:
            assert d.finished and d.error is None
    finally:
        world.close()
    return {"steps": d.steps_done, "rejected_messages": d.counter.snapshot().total}


@pytest.mark.parametrize(("placement", "lag"),
                         [("embedded", 0), ("embedded", 200), ("local", 200)])
def test_embedded_lockstep_and_the_local_runner_equal_the_synchronous_loop(tmp_path,
                                                                          placement, lag):
    params = BASE.replace(batch_lag=lag)
    expected = sync_knowledge("core2d", params, seed=3)
    ctx = context(tmp_path, "core2d", params, 3, f"t-{placement}-{lag}")
    summary = run_embedded(ctx) if placement == "embedded" else run_local(ctx)
    got = (tmp_path / "knowledge.json").read_text()
    assert json.loads(got)["dbns"], "nothing was learned: the comparison would be empty"
    assert got == expected
    assert summary["steps"] == STEPS
    assert summary["rejected_messages"] == 0
    if placement == "local":                # its checkpoints resume exactly (decision 41)
        from qlap_runtime.qlap.checkpoint import load_world_state

        assert load_world_state(tmp_path / "checkpoints" / "final") is not None


@pytest.mark.parametrize(("groups", "processes"), [
    ("two", ["world+perception+executor+planner", "contingency+landmarks"]),
    ("each", ["perception", "contingency", "landmarks", "planner", "executor", "world"])])
def test_processes_lockstep_equals_the_synchronous_loop(tmp_path, groups, processes):
    """The process groups (the step chain hosted with the planner and planreq in memory, the
    learners on one learner; docs/decisions.md 71) and one process per actor: the same
    knowledge as the synchronous loop, over real Zenoh on loopback."""
    params = BASE.replace(batch_lag=200)
    expected = sync_knowledge("core2d", params, seed=3)
    summary = run_processes(context(tmp_path, "core2d", params, 3, f"t-proc-{groups}"),
                            groups=groups)
    got = (tmp_path / "knowledge.json").read_text()
    assert json.loads(got)["dbns"], "nothing was learned: the comparison would be empty"
    assert got == expected
    assert summary["placement"] == "processes"
    assert summary["groups"] == processes
    assert summary["steps"] == STEPS
    assert sorted(summary["actors"]) == sorted(
        ["world", "perception", "contingency", "landmarks", "planner", "executor"])


def test_a_resolution_fixed_at_the_end_of_babbling_is_the_same_in_every_placement(tmp_path):
    """A Gymnasium world declares no resolution: its magnitudes' estimates are fixed on the
    step that ends babbling (docs/decisions.md 77), from the same history in the embedded
    placement with a batch lag as in the synchronous loop, so the knowledge is the same. At
    the end (3,000 steps) the history would give cos_theta 0.1192 and theta_dot 0.4935; the
    knowledge keeps 0.1155 and 0.4729, the estimates at step 1,500."""
    params = BASE.replace(batch_lag=200)
    expected = sync_knowledge("gym:Pendulum-v1", params, seed=3)
    res = json.loads(expected)["resolution"]
    assert res == {"torque": 0.04, "cos_theta": pytest.approx(0.11552, abs=1e-5),
                   "sin_theta": pytest.approx(0.12033, abs=1e-5),
                   "theta_dot": pytest.approx(0.47293, abs=1e-5)}
    run_embedded(context(tmp_path, "gym:Pendulum-v1", params, 3, "t-gym-fixed"))
    assert (tmp_path / "knowledge.json").read_text() == expected
