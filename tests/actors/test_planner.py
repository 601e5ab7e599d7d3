"""The planner actor (Algorithm 2 line 15; docs/decisions.md 56): every batch's plan
compilation off the step chain, applied by the executor at t + L, to the synchronous loop's
knowledge."""

from __future__ import annotations

import json

import worlds
from actors.planner import compiled_steps
from qlap_runtime import agent_run
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.placements.launcher import run_embedded
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext

STEPS = 4000
# Batches every 500 steps, k fixed and 15 data points (App. B.2): plans within 4,000 steps.
PARAMS = Params(babble_steps=1500, dbn_period=500, landmark_period=1000, batch_lag=200,
                k_fixed=5, min_data_points=15)


def test_the_planner_compiles_every_batch_and_the_agent_learns_what_the_sync_loop_learns(
        tmp_path):
    world = worlds.make("core2d")
    params = params_for_world(world, PARAMS)
    world.close()
    expected = agent_run.sync_knowledge("core2d", STEPS, 5, params)
    ctx = RunContext("t-planner", "core2d", STEPS, 5, params, out=tmp_path)
    summary = run_embedded(ctx)
    planner = summary["actors"]["planner"]
    # Batches at 500, 1000, …, 3500; each one's plan delta applies within the run.
    assert compiled_steps(ctx, -1) == list(range(500, STEPS, 500))
    assert planner["compilations"] == 7 and planner["rejected"] == 0
    got = (tmp_path / "knowledge.json").read_text()
    assert sum(len(a["plans"]) for a in json.loads(got)["actions"]) >= 3, "too few plans"
    assert got == expected


def test_a_light_request_compiles_what_a_deep_copy_compiles(tmp_path, monkeypatch):
    """Under the realtime clock the in-process request carries the learner's checkpoint state,
    rebuilt in the planner's thread (docs/decisions.md 82); forced in lockstep, the knowledge
    is still the synchronous loop's."""
    from actors.convert import LocalRequests

    put, lights = LocalRequests.put, []

    def light(self, run_id, agent, step, light=False, batch=None):
        lights.append(step)
        return put(self, run_id, agent, step, True)

    monkeypatch.setattr(LocalRequests, "put", light)
    world = worlds.make("core2d")
    params = params_for_world(world, PARAMS)
    world.close()
    expected = agent_run.sync_knowledge("core2d", STEPS, 5, params)
    run_embedded(RunContext("t-light", "core2d", STEPS, 5, params, out=tmp_path))
    assert lights == list(range(500, STEPS, 500))
    assert (tmp_path / "knowledge.json").read_text() == expected


def test_the_planner_compiles_on_the_learners_batch_copy(tmp_path, monkeypatch):
    """Embedded with a lag (decision 86): at each batch step the executor copies its learner
    once — the learners' batch computes on the copy, applying its operations, and the planner
    then compiles on that same copy — and the knowledge is the synchronous loop's."""
    from qlap_runtime.qlap.learner import ModelLearner

    copies: list[int] = []
    batch_copy = ModelLearner.batch_copy

    def counted(self):
        copies.append(self.step)
        return batch_copy(self)

    monkeypatch.setattr(ModelLearner, "batch_copy", counted)
    world = worlds.make("core2d")
    params = params_for_world(world, PARAMS)
    world.close()
    expected = agent_run.sync_knowledge("core2d", STEPS, 5, params)
    copies.clear()
    summary = run_embedded(RunContext("t-one-copy", "core2d", STEPS, 5, params, out=tmp_path))
    assert summary["actors"]["planner"]["compilations"] == len(range(500, STEPS - 200, 500))
    assert copies == list(range(500, STEPS, 500))        # one copy a batch step
    assert (tmp_path / "knowledge.json").read_text() == expected


async def test_the_planner_compiles_in_its_task_beside_the_step_chain_in_lockstep():
    """Beside the step chain (the embedded placement, the processes placement's default
    groups) in lockstep the planner compiles in its task (a worker thread would share the
    chain's GIL); in a process of its own, or under the realtime clock, in a worker thread
    (docs/decisions.md 93). The knowledge is the sync loop's either way (the test above)."""
    import zenoh

    from actors.planner import PlannerActor
    from qlap_runtime.bus import embedded_config
    from qlap_runtime.placements.groups import ACTORS, LAYOUTS

    def inline(groups: tuple, clock: str = "lockstep") -> bool:
        ctx = RunContext("t-planner-inline", "core2d", 100, 0, PARAMS, clock=clock,
                         groups=groups)
        with PlannerActor(session, ctx) as planner:
            return planner.inline

    with zenoh.open(embedded_config()) as session:
        assert inline((ACTORS,)) and inline(LAYOUTS["two"])
        assert not inline(LAYOUTS["each"]) and not inline(())
        assert not inline((ACTORS,), clock="realtime")


def test_a_light_request_copies_large_arrays_into_buffers_touched_before_the_run():
    """Decision 103: a realtime request's large arrays go into pooled buffers, prepared before
    the clock starts and given back once the planner's thread has rebuilt the learner, which
    shares no memory with them."""
    import numpy as np

    from actors.convert import ArrayPool, LocalRequests
    from qlap_runtime.qlap.checkpoint import learner_state

    world = worlds.make("core2d")
    params = params_for_world(world, PARAMS)
    agent, _ = agent_run.run_agent(world, 1200, 5, params=params)
    world.close()
    requests = LocalRequests()
    _, arrays = learner_state(agent.learner)
    large = {k for k, v in arrays.items() if v.nbytes >= ArrayPool.MIN_BYTES}
    assert large == {"perception.hist_x", "perception.hist_q"}
    assert requests.prepare(agent.learner) == sum(arrays[k].nbytes for k in large)
    pooled = {id(b) for bufs in requests.pool.free.values() for b in bufs}
    assert len(pooled) == 2

    requests.put("r", agent, 1200, light=True)
    _, (meta, copied) = requests.agents[("r", 1200)]
    assert {k for k, v in copied.items() if id(v) in pooled} == large    # no fresh pages
    assert requests.pool.free == {key: [] for key in requests.pool.free}
    for k, v in copied.items():
        assert np.array_equal(v, arrays[k], equal_nan=True), k
    copy, applied = requests.take("r", 1200)
    assert not applied
    restored_meta, restored = learner_state(copy.learner)
    assert restored_meta["step"] == meta["step"] == agent.learner.step
    for k in large:                                 # the learner copied what it read
        assert np.array_equal(restored[k], arrays[k], equal_nan=True)
        assert not any(np.shares_memory(restored[k], copied[j]) for j in large)
    assert {id(b) for bufs in requests.pool.free.values() for b in bufs} == pooled
    small = np.zeros(10)
    assert requests.pool.copy(small) is not small and requests.pool.free    # small: a copy
