"""One perception a step on the hosted step chain (docs/decisions.md 83).

The hosted perception actor perceives with the executor's learner's own perception, and the
executor learns from that percept with ``ModelLearner.observe_own``: the learner must end in
the state the synchronous loop's ``observe`` gives (perceive, then lines 4–5), batches,
landmarks and discontinuities included; and an embedded run perceives each step once.
"""

from __future__ import annotations

import json

import numpy as np

import worlds
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.placements.launcher import run_embedded
from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import learner_state
from qlap_runtime.qlap.delta import AddLandmark, Delta
from qlap_runtime.qlap.perception import Perception
from tests.actors.test_lockstep import STEPS, context, sync_knowledge

PARAMS = Params(babble_steps=1500, dbn_period=500, landmark_period=1000)


def _same_state(a: ModelLearner, b: ModelLearner) -> None:
    """Equal checkpoint states, but for the splits an agent takes from its learner."""
    meta_a, arrays_a = learner_state(a)
    meta_b, arrays_b = learner_state(b)
    meta_a.pop("splits")
    meta_b.pop("splits")
    assert json.dumps(meta_a, sort_keys=True) == json.dumps(meta_b, sort_keys=True)
    assert arrays_a.keys() == arrays_b.keys()
    for k in arrays_a:
        assert np.array_equal(arrays_a[k], arrays_b[k], equal_nan=True), k


def test_observe_own_learns_what_observe_learns():
    """A real core2d world babbled by the synchronous agent (seed 5, 3,000 steps, lag 0): a
    second learner fed through its own perception and ``observe_own`` ends in the state of the
    agent's learner (``observe``), its batches (new DBNs, landmarks that renumber the
    percepts) computed and applied on it at the same steps, a landmark applied to both at
    step 1,200, and a discontinuity every 700 steps."""
    world = worlds.make("core2d")
    params = params_for_world(world, PARAMS.replace(babble_steps=5000, batch_lag=0))
    agent = Agent(world.variables, params, seed=5)
    own = ModelLearner(world.variables, params)
    own.auto_batches = False
    obs = world.reset(seed=5)
    landmarks = 0
    try:
        for t in range(3000):
            jump = t > 0 and t % 700 == 0
            full = {**obs, **agent.motor}
            motor = agent.step(t, obs, discontinuity=jump)
            per: Perception = own.perception
            p_own = own.observe_own(per.perceive(t, per.vector(full), copy=False,
                                                 discontinuity=jump))
            if t > 0 and t % params.dbn_period == 0:
                own.reliable_actions = set(agent.learner.reliable_actions)
                delta = own.compute_batch(t)
                landmarks += sum(type(op).__name__ == "AddLandmark" for op in delta.ops)
                own.apply_delta(delta)
            if t == 1200:                       # a landmark on both: the percepts renumber
                var = next(v.index for v in own.table if v.name == "h_x")
                x = float(p_own.x[var]) - 0.05
                delta = Delta(t, t, t, (AddLandmark(var, x, x, "event", t),))
                agent.learner.apply_delta(delta)
                own.apply_delta(delta)
                landmarks += 1
            p_sync = agent.learner.perception
            assert np.array_equal(p_sync.prev_q, p_own.q)
            obs = world.step(motor)
    finally:
        world.close()
    assert agent.learner.dbns, "nothing was learned: the comparison would be empty"
    assert landmarks
    _same_state(agent.learner, own)


def test_an_embedded_run_perceives_each_step_once(tmp_path, monkeypatch):
    """The step chain perceives each of its steps once (the perception actor with the
    executor's learner's perception; no second ``ingest`` of the percept by the executor) and
    still learns the synchronous loop's knowledge."""
    calls = {"perceive": 0, "ingest": 0}
    perceive, ingest = Perception.perceive, Perception.ingest

    def counted_perceive(self, *args, **kw):
        calls["perceive"] += 1
        return perceive(self, *args, **kw)

    def counted_ingest(self, *args, **kw):
        calls["ingest"] += 1
        return ingest(self, *args, **kw)

    monkeypatch.setattr(Perception, "perceive", counted_perceive)
    monkeypatch.setattr(Perception, "ingest", counted_ingest)
    params = PARAMS.replace(batch_lag=200)
    expected = sync_knowledge("core2d", params, seed=3)
    calls.update(perceive=0, ingest=0)
    ctx = context(tmp_path, "core2d", params, 3, "t-one-perception")
    summary = run_embedded(ctx)
    assert summary["steps"] == STEPS
    assert calls == {"perceive": STEPS, "ingest": 0}
    assert (tmp_path / "knowledge.json").read_text() == expected
