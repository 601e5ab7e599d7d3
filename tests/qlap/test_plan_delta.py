"""Plan compilation as a delta (Algorithm 2 line 15; docs/decisions.md 56): computed on the
batch's snapshot at t, applied at t + L, its operations typed and checked on the wire."""

from __future__ import annotations

import copy
import json
import tempfile

import numpy as np
import pytest

from qlap_runtime.qlap import Params
from qlap_runtime.qlap.agent import Agent
from qlap_runtime.qlap.checkpoint import load_agent, save_agent
from qlap_runtime.qlap.plan_delta import (
    AddPlan,
    PlanContexts,
    PlanDelta,
    Rebuild,
    plan_op_from_json,
    q_from_json,
    q_to_json,
)
from tests.qlap.toyworld import SPECS, ToyWorld

LAG = 100
B = 12_000
"""A batch step whose compilation removes, adds and rebuilds plans in the toy world."""
PARAMS = Params(babble_steps=3_000, dbn_period=1_000, landmark_period=2_000, batch_lag=LAG)


def run(agent: Agent, world: ToyWorld, start: int, stop: int) -> None:
    for t in range(start, stop):
        world.step(agent.step(t, {"x": world.x})["u"])


@pytest.fixture(scope="module")
def at_batch() -> tuple[Agent, ToyWorld]:
    """An agent that has just taken the batch step 8,000 (its plan delta pending)."""
    agent, world = Agent(SPECS, PARAMS, seed=0), ToyWorld()
    run(agent, world, 0, B + 1)
    return agent, world


def test_the_plan_delta_of_a_batch_waits_for_t_plus_lag(at_batch):
    agent, _ = at_batch
    (delta,) = agent.pending_plans
    assert (delta.computed_at, delta.apply_at) == (B, B + LAG)
    assert any(isinstance(op, PlanContexts) for op in delta.ops)
    rebuilt = [op.plan_id for op in delta.ops if isinstance(op, Rebuild)]
    assert rebuilt and rebuilt == sorted(rebuilt)   # every surviving plan, by id


def test_plan_deltas_round_trip_through_json_byte_exact(at_batch):
    agent, _ = at_batch
    (delta,) = agent.pending_plans
    wire = json.loads(json.dumps(delta.to_json(), allow_nan=False))
    back = PlanDelta.from_json(wire)
    assert back.to_json() == delta.to_json()
    q = np.array([[0.5, -np.inf], [1e-300, -0.0]])
    assert q_from_json("x", json.loads(json.dumps(q_to_json(q)))).tobytes() == q.tobytes()


def test_new_plans_exist_from_t_plus_lag_and_keep_the_q_learned_meanwhile(at_batch):
    agent, world = _copy(*at_batch)
    (delta,) = agent.pending_plans
    added = {op.plan_id for op in delta.ops if isinstance(op, AddPlan)}
    at_t = {pid: plan.q.copy() for pid, plan in agent.plans.items()}
    seen: dict[str, dict[int, np.ndarray]] = {}
    apply = agent.apply_plans

    def observed(d, p, value_maps):                    # the Q-tables around the apply
        seen["before"] = {pid: plan.q.copy() for pid, plan in agent.plans.items()}
        apply(d, p, value_maps)
        seen["after"] = {pid: plan.q.copy() for pid, plan in agent.plans.items()}

    agent.apply_plans = observed
    run(agent, world, B + 1, B + LAG)
    assert not seen and not added & set(agent.plans)   # not yet
    run(agent, world, B + LAG, B + 1 + LAG)
    assert not agent.pending_plans
    assert added <= set(agent.plans)
    assert all(agent.plans[pid].created == B + LAG for pid in added)
    # Sarsa and Dyna went on between t and t + L: a plan the delta rebuilds without a
    # change keeps the executor's values, not those of the snapshot at t.
    kept = [pid for pid in seen["before"] if pid in seen["after"]
            and seen["after"][pid].shape == seen["before"][pid].shape]
    assert kept
    assert all(seen["after"][pid].tobytes() == seen["before"][pid].tobytes() for pid in kept)
    assert any(seen["before"][pid].tobytes() != at_t[pid].tobytes() for pid in kept)


def test_compiling_on_a_copy_leaves_the_agent_as_it_was(at_batch):
    agent, _ = at_batch
    before = json.dumps(agent.knowledge(), sort_keys=True)
    qs = {pid: plan.q.copy() for pid, plan in agent.plans.items()}
    ctxs = {pid: plan.context_o for pid, plan in agent.plans.items()}
    work = agent.learner.batch_copy()
    agent.planning_copy(work).compile_plans(B, B + LAG)
    assert json.dumps(agent.knowledge(), sort_keys=True) == before
    assert {pid: plan.context_o for pid, plan in agent.plans.items()} == ctxs
    assert all(agent.plans[pid].q.tobytes() == q.tobytes() for pid, q in qs.items())


def test_a_malformed_operation_is_refused_naming_its_field():
    with pytest.raises(ValueError, match="add_plan: q.values"):
        plan_op_from_json(["add_plan", 1, 2, {"shape": [1, 2], "na": "AA==", "values": ""}])
    with pytest.raises(ValueError, match="remove_plan: plan_id"):
        plan_op_from_json(["remove_plan", -1])
    with pytest.raises(ValueError, match="unknown plan delta operation"):
        plan_op_from_json(["add_dbn", 1])
    with pytest.raises(ValueError, match="computed_at, apply_at"):
        PlanDelta.from_json({"computed_at": 1, "ops": []})


def _copy(agent: Agent, world: ToyWorld) -> tuple[Agent, ToyWorld]:
    """An independent agent in the same state (a checkpoint round trip, which keeps the
    pending plan delta) and a copy of its world."""
    with tempfile.TemporaryDirectory() as tmp:
        save_agent(agent, tmp)
        return load_agent(tmp), copy.deepcopy(world)
