"""The whole agent (ch. 5–6) in the toy world: it learns to act and reaches goals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from qlap_runtime.qlap import Params
from qlap_runtime.qlap.agent import FAIL, RUN, Agent, Frame
from qlap_runtime.qlap.checkpoint import load_agent, save_agent
from tests.qlap.toyworld import SPECS, ToyWorld

PARAMS = Params(babble_steps=14_000)


def run(agent: Agent, world: ToyWorld, start: int, stop: int) -> None:
    for t in range(start, stop):
        motor = agent.step(t, {"x": world.x})
        world.step(motor["u"])


@pytest.fixture(scope="module")
def trained() -> tuple[Agent, ToyWorld]:
    agent, world = Agent(SPECS, PARAMS, seed=0), ToyWorld()
    run(agent, world, 0, 30_000)
    return agent, world


def key_of(agent: Agent, name: str, value: int) -> tuple[int, int]:
    return agent.table.index(name), value


def test_the_agent_learns_a_reliable_action_to_move_x_up(trained):
    agent, _ = trained
    up = key_of(agent, "x.dot", 2)
    plans = [p for p in agent.plans.values() if p.action == up]
    assert plans, "no plan for a(ẋ, [+])"
    labels = [agent.learner.dbn_label(agent.learner.dbns[p.dbn_id]) for p in plans]
    assert any(lbl.startswith("⟨") and "u→(0.3" in lbl for lbl in labels), labels
    stats = agent.actions[up]
    assert stats.calls >= 100
    # Practice includes calls with x pinned at its upper bound, where no plan can succeed.
    assert stats.rel() > 0.85


def goal_trials(agent: Agent, world: ToyWorld, target: tuple[int, int], starts, steps=300):
    agent.learning = False
    t = agent.step_count + 1
    reached = 0
    for x0 in starts:
        world.x = float(x0)
        agent.new_episode()
        agent.set_goal(*target)
        for _ in range(steps):
            motor = agent.step(t, {"x": world.x})
            t += 1
            if agent._last_percept.q[target[0]] == target[1]:
                reached += 1
                break
            world.step(motor["u"])
    agent.clear_goal()
    return reached


def test_goal_mode_makes_x_move_up_from_inside_the_range(trained):
    agent, world = trained
    rng = np.random.default_rng(3)
    up = key_of(agent, "x.dot", 2)
    assert goal_trials(agent, world, up, rng.uniform(1, 9, 20), steps=50) >= 19


def test_goal_mode_reaches_the_landmarks_of_x_from_either_side(trained):
    agent, world = trained
    x = agent.table.index("x")
    space = agent.learner.perception.spaces[x]
    assert len(space.landmarks) >= 2
    low = 1                                      # the landmark near 0: reached from above
    high = space.size - 2                        # the landmark near 10: reached from below
    assert space.bounds(low)[0] <= 1.0
    assert space.bounds(high)[1] >= 9.0
    rng = np.random.default_rng(4)
    assert goal_trials(agent, world, (x, low), rng.uniform(3, 7, 10)) >= 8
    assert goal_trials(agent, world, (x, high), rng.uniform(3, 7, 10)) >= 8


def test_knowledge_lists_actions_with_plans(trained):
    agent, _ = trained
    k = agent.knowledge()
    acts = {a["label"]: a for a in k["actions"]}
    assert "a(x.dot, [+])" in acts
    plan = acts["a(x.dot, [+])"]["plans"][0]
    assert set(plan) >= {"dbn", "dbn_label", "rel_o", "calls", "context_o"}
    assert any(d["plan"] for d in k["dbns"])


def test_checkpoint_resume_gives_identical_knowledge(tmp_path):
    params = Params(babble_steps=4000)
    a, wa = Agent(SPECS, params, seed=1), ToyWorld()
    run(a, wa, 0, 16_000)
    b, wb = Agent(SPECS, params, seed=1), ToyWorld()
    run(b, wb, 0, 9_999)
    save_agent(b, tmp_path / "ck")
    c = load_agent(tmp_path / "ck")
    run(c, wb, 9_999, 16_000)
    assert json.dumps(c.knowledge()) == json.dumps(a.knowledge())


def test_same_seed_same_behaviour():
    params = Params(babble_steps=3000)
    motors = []
    for _ in range(2):
        agent, world = Agent(SPECS, params, seed=7), ToyWorld()
        seq = []
        for t in range(7000):
            m = agent.step(t, {"x": world.x})
            seq.append(m["u"])
            world.step(m["u"])
        motors.append(seq)
    assert motors[0] == motors[1]


def test_call_list_refuses_a_plan_whose_antecedent_is_already_in_it(trained):
    agent, _ = trained
    up = key_of(agent, "x.dot", 2)
    plan = next(p for p in agent.plans.values() if p.action == up)
    dbn = agent.learner.dbns[plan.dbn_id]
    p = agent._last_percept
    agent.call_list = [Frame((dbn.antecedent.var, dbn.antecedent.value), p.step,
                             is_motor=True)]
    assert agent._pick_plan([plan], p) is None          # excluded (§6.1.2)
    agent.call_list = []
    assert agent._pick_plan([plan], p) == 0


def test_termination_by_resource_limits_and_stuck(trained):
    agent, _ = trained
    p = agent._last_percept
    plan = next(iter(agent.plans.values()))
    f = Frame(plan.action, p.step - agent.params.option_max_steps, plan_id=plan.id)
    assert agent._stuck_or_out_of_time(f, plan, p)       # 300 steps (§5.2.3)
    f = Frame(plan.action, p.step, plan_id=plan.id)
    assert not agent._stuck_or_out_of_time(f, plan, p)   # first look: state recorded
    f.last_change = p.step - agent.params.stuck_steps
    assert agent._stuck_or_out_of_time(f, plan, p)       # nothing changed in 10 steps
    f = Frame(plan.action, p.step, plan_id=plan.id, calls=agent.params.option_max_calls)
    agent.call_list = [f]
    assert agent._next_sub(0, p) == FAIL                 # 5 action calls (§5.2.3)
    agent.call_list = []


def test_no_plan_means_the_action_fails_and_goal_mode_moves_randomly():
    agent, world = Agent(SPECS, PARAMS, seed=0), ToyWorld()
    run(agent, world, 0, 50)
    agent.set_goal("x.dot", "+")
    m1 = agent.step(50, {"x": world.x})
    assert agent.call_list == []                         # no plan: fails at once
    m2 = agent.step(51, {"x": world.x})
    assert -1 <= m1["u"] <= 1 and -1 <= m2["u"] <= 1
    agent.set_goal("x.dot", "+", idle="zero")
    assert agent.step(52, {"x": world.x}) == {"u": 0.0}
    assert RUN == "run"
    with pytest.raises(ValueError, match="cannot name value"):
        agent.set_goal("x.dot", "up")
    with pytest.raises(KeyError, match="unknown variable 'y'"):
        agent.set_goal("y", 0)
