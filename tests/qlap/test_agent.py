"""The whole agent (ch. 5–6) in the toy world: it learns to act and reaches goals."""

from __future__ import annotations

import copy
import dataclasses
import gc
import json
import weakref

import numpy as np
import pytest

from qlap_runtime.qlap import Params
from qlap_runtime.qlap.agent import FAIL, RUN, Agent, Frame
from qlap_runtime.qlap.checkpoint import load_agent, save_agent
from qlap_runtime.qlap.dbn import CHANGE, DBN, MAGNITUDE
from qlap_runtime.qlap.perception import Percept
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


def test_a_body_moving_at_a_steady_rate_is_stuck_when_nothing_else_changes(trained):
    """§5.2.3 read on qualitative values (docs/decisions.md 20): a self variable that stays
    [+] for 10 steps, with the plan's state unchanged, does not count as a change."""
    agent, _ = trained
    p = agent._last_percept
    plan = next(iter(agent.plans.values()))
    xdot = agent.table.index("x.dot")
    q = p.q.copy()
    q[xdot] = 2                                          # [+]: moving, and staying so
    moving = dataclasses.replace(p, q=q)
    agent.self_vars = {xdot}
    f = Frame(plan.action, p.step, plan_id=plan.id)
    assert not agent._stuck_or_out_of_time(f, plan, moving)   # first look: state recorded
    f.last_change = p.step - agent.params.stuck_steps + 1
    assert not agent._stuck_or_out_of_time(f, plan, moving)   # 9 steps: not yet
    f.last_change = p.step - agent.params.stuck_steps
    assert agent._stuck_or_out_of_time(f, plan, moving)       # 10 steps at [+]: stuck
    q2 = q.copy()
    q2[xdot] = 1                                          # [+] → [0]: a change
    assert not agent._stuck_or_out_of_time(f, plan, dataclasses.replace(p, q=q2))


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
    with pytest.raises(ValueError, match="has no value 'up'"):
        agent.set_goal("x.dot", "up")
    with pytest.raises(KeyError, match="unknown variable 'y'"):
        agent.set_goal("y", 0)


# --- evaluation is frozen and clean (§7.2) ----------------------------------------------------


def knowledge_snapshot(agent: Agent) -> dict[str, bytes]:
    """Everything the agent has learned, as bytes: learner knowledge (with the resolutions the
    perception derives from its history), actions (with IAC histories), plans (Q, traces,
    second-order statistics) and DBN statistics."""
    k = agent.knowledge()
    out = {"knowledge": json.dumps(k, sort_keys=True).encode(),
           "actions": json.dumps(agent.actions.to_json(), sort_keys=True).encode(),
           "self": json.dumps(sorted(agent.self_vars)).encode()}
    for pid, pl in sorted(agent.plans.items()):
        assert pl.sarsa is not None
        for name in ("q", "cpt_s", "cpt_f", "call_x", "call_ok"):
            out[f"plan{pid}.{name}"] = np.ascontiguousarray(getattr(pl, name)).tobytes()
        out[f"plan{pid}.e"] = pl.sarsa.e.tobytes()
        out[f"plan{pid}.n"] = json.dumps([pl.calls, pl.successes, pl.call_n, pl.call_head,
                                          list(pl.context_o), pl.ever_reliable]).encode()
    for did, d in sorted(agent.learner.dbns.items()):
        out[f"dbn{did}"] = b"".join(np.ascontiguousarray(a).tobytes()
                                    for a in (d.cpt_s, d.cpt_f, d.act_x, d.act_ok))
        out[f"dbn{did}.n"] = json.dumps([d.act_n, d.total, d.ever_reliable]).encode()
    return out


def evaluation_copy(trained, tmp_path):
    """The trained agent saved and loaded as ``qlap eval`` loads it, its knowledge snapshot and
    a toy task world."""
    from tests.qlap.toyworld import ToyTaskWorld

    agent, _ = trained
    agent.learning = True
    save_agent(agent, tmp_path / "ck")
    ev = load_agent(tmp_path / "ck")
    return ev, knowledge_snapshot(ev), ToyTaskWorld()


def test_evaluation_changes_nothing_the_agent_learned(trained, tmp_path):
    from qlap_runtime.agent_run import evaluate, goal_policy
    from tests.qlap.toyworld import ToyTaskWorld
    from worlds.evaluate import run_trials

    ev, before, world = evaluation_copy(trained, tmp_path)
    res = run_trials(world, "x_up", 10, 3, goal_policy(ev, world, "x_up"))
    assert res["successes"] >= 8                         # the plans were used
    assert ev.counters.successes + ev.counters.failures >= 10
    ev.end_trial()                                       # the last trial's Sarsa, undone
    after = knowledge_snapshot(ev)
    assert [k for k in before if before[k] != after[k]] == []
    # the command-line path loads the checkpoint itself; same result for the same seed
    again = evaluate(tmp_path / "ck", ToyTaskWorld(), "x_up", 10, 3)
    assert again["rewards"] == res["rewards"]


def test_evaluation_can_pursue_another_goal_than_the_tasks(trained, tmp_path):
    """``qlap eval --goal``: the agent pursues the given goal, the task still judges. Pursuing
    ẋ = [−] in x_up trials (goal ẋ = [+]) is slow where pursuing the task's own goal is not."""
    from qlap_runtime.agent_run import evaluate
    from tests.qlap.toyworld import ToyTaskWorld
    from worlds.base import Goal

    evaluation_copy(trained, tmp_path)
    own = evaluate(tmp_path / "ck", ToyTaskWorld(), "x_up", 10, 3)
    same = evaluate(tmp_path / "ck", ToyTaskWorld(), "x_up", 10, 3, pursue=Goal("x.dot", "+"))
    down = evaluate(tmp_path / "ck", ToyTaskWorld(), "x_up", 10, 3, pursue=Goal("x.dot", "-"))
    assert own["successes"] >= 8 and "pursued" not in own
    assert same["rewards"] == own["rewards"] and same["pursued"] == "x.dot=+"
    # Pushing x down first: the trials end only once x rises after all (1.5 → 9.5 steps).
    assert own["mean_steps"] < 2 and down["mean_steps"] > 5 and down["pursued"] == "x.dot=-"
    # Every step of the policy counted; with a plan for its goal the agent idles only at a
    # trial's first step (its history just broken: no direction of change known yet).
    assert own["policy_steps"] == round(own["mean_steps"] * 10)
    assert own["steps_without_plan"] == 10
    still = evaluate(tmp_path / "ck", ToyTaskWorld(), "x_up", 10, 3, pursue=Goal("x.dot", "0"))
    # No plan for [0]: in every step either ẋ = [0] already held (nothing to do) or the agent
    # moved randomly; a goal that holds is not counted as one without a plan.
    assert still["steps_goal_held"] > 0 and still["steps_without_plan"] > 0
    assert still["steps_without_plan"] + still["steps_goal_held"] == still["policy_steps"]
    with pytest.raises(KeyError, match="unknown variable 'y.dot'"):
        evaluate(tmp_path / "ck", ToyTaskWorld(), "x_up", 2, 3, pursue=Goal("y.dot", "+"))
    with pytest.raises(ValueError, match="qlap policy"):
        evaluate(None, ToyTaskWorld(), "x_up", 2, 3, policy="random", pursue=Goal("x.dot", "+"))


def test_evaluation_leaves_the_perception_history_alone(trained, tmp_path):
    from qlap_runtime.agent_run import goal_policy
    from worlds.evaluate import run_trials

    ev, before, world = evaluation_copy(trained, tmp_path)
    run_trials(world, "x_up", 10, 3, goal_policy(ev, world, "x_up"))
    ev.end_trial()
    assert knowledge_snapshot(ev) == before


def test_sarsa_adapts_within_a_trial_and_the_next_trial_starts_from_the_checkpoint(
        trained, tmp_path):
    """§5.2.2 with learning off (``Params.sarsa_in_trials``): Q moves during a trial; a new
    episode (or :meth:`Agent.end_trial`) puts every Q-table and trace back, bit for bit."""
    import dataclasses

    from qlap_runtime.agent_run import goal_policy
    from worlds.evaluate import run_trials

    ev, before, world = evaluation_copy(trained, tmp_path)
    policy = goal_policy(ev, world, "x_up")
    # One trial at a time until one made a Sarsa update (a trial whose first call succeeds
    # makes none): what `trained` is depends on the tests before, so their number does too.
    for seed in range(3, 23):
        run_trials(world, "x_up", 1, seed, policy)
        during = knowledge_snapshot(ev)                  # this trial not yet undone
        changed = sorted(k for k in before if before[k] != during[k])
        if changed:
            break
    assert changed and all(k.startswith("plan") and k.endswith((".q", ".e")) for k in changed)
    ev.new_episode()
    assert knowledge_snapshot(ev) == before
    # switched off: not even within a trial
    ev2 = load_agent(tmp_path / "ck")
    ev2.params = dataclasses.replace(ev2.params, sarsa_in_trials=False)
    run_trials(world, "x_up", 3, 3, goal_policy(ev2, world, "x_up"))
    assert knowledge_snapshot(ev2) == before


def test_the_same_trials_with_learning_on_would_change_the_knowledge(trained, tmp_path):
    """The control of the test above: the snapshot does see what practice changes."""
    from worlds.evaluate import run_trials

    ev, before, world = evaluation_copy(trained, tmp_path)
    from qlap_runtime.agent_run import goal_policy

    policy = goal_policy(ev, world, "x_up")
    ev.learning = True                                   # (goal_policy turned it off)
    run_trials(world, "x_up", 3, 3, policy)
    after = knowledge_snapshot(ev)
    changed = {k.split(".")[0] for k in before if before[k] != after[k]}
    assert "actions" in changed and any(k.startswith("plan") for k in changed)


def test_a_new_episode_puts_the_motors_at_rest_and_restarts_babbling():
    from tests.qlap.toyworld import Spec

    specs = (Spec("u", "motor", -1.0, 1.0), Spec("g", "motor", 0.2, 1.0), Spec("x", "magnitude"))
    agent = Agent(specs, PARAMS, seed=5)
    assert agent.motor == {"u": 0.0, "g": 0.2}           # rest: 0, or the nearest in range
    for t in range(30):
        agent.step(t, {"x": 5.0})
    assert agent.motor["u"] != 0.0 and agent.babbler.counters.any()
    agent.new_episode()
    assert agent.motor == {"u": 0.0, "g": 0.2}
    assert not agent.babbler.counters.any() and (agent.babbler.limits == -1).all()
    # the first babbling step after it draws a new value and hold for every motor
    rng = np.random.default_rng(0)
    agent.rng.bit_generator.state = rng.bit_generator.state
    motor, _ = agent.babbler.step()
    expect = np.random.default_rng(0)
    u = expect.uniform(-1.0, 1.0)
    expect.integers(0, PARAMS.babble_max_hold + 1)
    g = expect.uniform(0.2, 1.0)
    assert motor == {"u": u, "g": g}
    # the previous values are forgotten: no direction of change on the next step
    p_motor = agent.step(30, {"x": 7.0})
    assert p_motor is not None
    xdot = agent.table.index("x.dot")
    assert agent._last_percept.q[xdot] == -1


def practising(agent: Agent, world: ToyWorld, t: int, min_frames: int = 2) -> int:
    """Step until the agent is practising with at least ``min_frames`` frames."""
    for _ in range(5000):
        motor = agent.step(t, {"x": world.x})
        world.step(motor["u"])
        t += 1
        if agent.mode == "practice" and len(agent.call_list) >= min_frames:
            return t
    raise AssertionError("the agent never practised")


def test_a_discontinuity_ends_the_call_list_without_recording(trained):
    import copy

    agent, world = copy.deepcopy(trained)
    agent.learning = True
    agent.clear_goal()
    world = ToyWorld(5.0)
    t = practising(agent, world, agent.step_count + 1)
    calls = {key: st.calls for key, st in agent.actions.items()}
    interrupts = agent.counters.call_list_interrupts
    agent.step(t, {"x": 2.0}, discontinuity=True)        # the world jumped
    assert agent.counters.call_list_interrupts == interrupts + 1
    # neither success nor failure recorded for any action
    assert {key: st.calls for key, st in agent.actions.items()} == calls
    assert agent._last_percept.discontinuity
    assert agent._last_percept.q[agent.table.index("x.dot")] == -1
    # with no direction of change nothing is applicable: a babbling command, no failed call
    assert agent.call_list == [] and agent.mode in ("command", "idle")


# --- motors whose range does not straddle a landmark (§5.5) ------------------------------------


def test_a_motor_value_out_of_range_is_not_applicable_and_never_crashes():
    from qlap_runtime.qlap.delta import AddLandmark, Delta
    from tests.qlap.toyworld import Spec

    specs = (Spec("g", "motor", 0.0, 1.0), Spec("x", "magnitude"))
    agent = Agent(specs, PARAMS, seed=1)
    for t in range(3):
        agent.step(t, {"x": 1.0})
    g = agent.table.index("g")
    # a landmark at 0 (as core's u_UG had): (−∞, 0) is a value g can never take
    agent.learner.apply_delta(Delta(1, 2, 2, (AddLandmark(g, 0.0, 0.0, "dbn", 2),)))
    agent.step(3, {"x": 1.0})
    space = agent.learner.perception.spaces[g]
    assert space.bounds(0)[1] == 0.0
    assert not agent._usable(g, 0) and agent._usable(g, 1) and agent._usable(g, 2)
    p = agent._last_percept
    before = dict(agent.motor)
    assert agent._call((g, 0), p) == FAIL                # fails at call, no ValueError
    assert agent.motor == before and agent.call_list == []
    assert agent._call((g, 2), p) == RUN
    assert 0.0 < agent.motor["g"] <= space.bounds(2)[1]
    agent.call_list.clear()
    agent.set_goal(g, 0)                                 # goal mode on it: moves randomly
    for t in range(4, 10):
        m = agent.step(t, {"x": 1.0})
        assert 0.0 <= m["g"] <= 1.0


# --- plans: which DBNs become plans (§6.2.2) ---------------------------------------------------


def fresh_agent(specs, params: Params, landmarks: dict[str, float] | None = None) -> Agent:
    """An agent that has seen three steps, with point landmarks added through a delta."""
    from qlap_runtime.qlap.delta import AddLandmark, Delta

    agent = Agent(specs, params, seed=0)
    obs = {s.name: 5.0 for s in specs if s.kind == "magnitude"}
    for t in range(3):
        agent.step(t, obs)
    ops = tuple(AddLandmark(agent.table.index(n), v, v, "event", 2)
                for n, v in (landmarks or {}).items())
    agent.learner.apply_delta(Delta(1, 2, 2, ops))
    agent.step(3, obs)
    return agent


def add_dbn(agent: Agent, dbn_id: int, kind: str, ante: tuple[int, int, int],
            cons: tuple[int, int, int], s: float, f: float, reliable: bool = True) -> DBN:
    from qlap_runtime.qlap.variables import Event

    dbn = DBN(dbn_id, kind, Event(*ante), Event(*cons), (), 0, len(agent.table), 200)
    dbn.cpt_s, dbn.cpt_f = np.array([s]), np.array([f])
    dbn.ever_reliable = reliable
    agent.learner.dbns[dbn_id] = dbn
    return dbn


def plan_dbns(agent: Agent) -> list[int]:
    return sorted(pl.dbn_id for pl in agent.plans.values())


def test_competing_dbns_are_converted_best_first():
    agent = fresh_agent(SPECS, PARAMS.replace(max_plans_per_action=1))
    u, xdot = agent.table.index("u"), agent.table.index("x.dot")
    # brel (B.4): DBN 0: (20 + 1)/(25 + 2) = 0.778; DBN 1: (40 + 1)/(42 + 2) = 0.932
    add_dbn(agent, 0, CHANGE, (u, 2, 0), (xdot, 2, 0), 20, 5)
    add_dbn(agent, 1, CHANGE, (u, 1, 0), (xdot, 2, 0), 40, 2)
    agent._convert_dbns_to_plans(100)
    assert plan_dbns(agent) == [1]                       # not DBN 0, though its id is lower


def test_a_plan_never_called_gives_its_slot_up_after_dbn_max_age():
    agent = fresh_agent(SPECS, PARAMS.replace(max_plans_per_action=1))
    u, xdot = agent.table.index("u"), agent.table.index("x.dot")
    add_dbn(agent, 0, CHANGE, (u, 2, 0), (xdot, 2, 0), 20, 5)
    agent._convert_dbns_to_plans(100)
    assert plan_dbns(agent) == [0]
    add_dbn(agent, 1, CHANGE, (u, 1, 0), (xdot, 2, 0), 40, 2)
    agent._convert_dbns_to_plans(100 + 99_999)           # called 0 < 30 times, young: kept
    assert plan_dbns(agent) == [0]
    agent._convert_dbns_to_plans(100 + 100_000)          # 100,000 steps old: replaced
    assert plan_dbns(agent) == [1]


def test_a_goal_names_a_magnitude_value_by_label_number_or_index():
    """``qlap eval --goal h_x=…`` (:meth:`Agent.set_goal`): x has the landmark 5, so
    Q(x) = {(−∞, 5), [5], (5, +∞)} = 0, 1, 2."""
    agent = nrp_agent(PARAMS)
    x = agent.table.index("x")
    assert agent.learner.value_label(x, 0) == "(-inf, 5)"
    for text, q in [("(-inf, 5)", 0), ("(−∞, 5)", 0), ("[5]", 1), ("(5, +inf)", 2),
                    ("(5,inf)", 2), ("(5, ∞)", 2), ("4.2", 0), ("5", 1), ("1e3", 2), ("#1", 1),
                    ("\u22124.2", 0), ("\u22121e3", 0)]:    # qlap show's minus
        assert agent.set_goal("x", text) == (x, q), text
    assert agent.set_goal("x.dot", "+") == (agent.table.index("x.dot"), 2)
    with pytest.raises(ValueError, match=r"x has no value 'nan': .*\(-inf, 5\), 5, \(5, \+inf\)"):
        agent.set_goal("x", "nan")
    with pytest.raises(ValueError, match=r"outside Q\(x\) \(0..2\)"):
        agent.set_goal("x", "#3")
    with pytest.raises(ValueError, match=r"x.dot \(change\) has no value 'up': one of -, \[-\]"):
        agent.set_goal("x.dot", "up")


def nrp_agent(params: Params) -> Agent:
    """Motor DBNs 0–1 for a(ẋ, [±]), magnitude DBNs 2–3 reaching x = 5 from below and from
    above, and DBN 4 ⟨↑x→[5] ⇒ ẏ→[+]⟩, whose antecedent only DBN 2's plan achieves."""
    from tests.qlap.toyworld import Spec

    specs = (*SPECS, Spec("y", "magnitude"))
    agent = fresh_agent(specs, params, landmarks={"x": 5.0})
    u, x = agent.table.index("u"), agent.table.index("x")
    xdot, ydot = agent.table.index("x.dot"), agent.table.index("y.dot")
    add_dbn(agent, 0, CHANGE, (u, 2, 0), (xdot, 2, 0), 40, 2)         # ⟨u→(0,∞) ⇒ ẋ→[+]⟩
    add_dbn(agent, 1, CHANGE, (u, 0, 0), (xdot, 0, 0), 40, 2)         # ⟨u→(−∞,0) ⇒ ẋ→[−]⟩
    add_dbn(agent, 2, MAGNITUDE, (xdot, 2, 0), (x, 1, 1), 0, 0, False)   # ⟨ẋ→[+] ⇒ ↑x→[5]⟩
    add_dbn(agent, 3, MAGNITUDE, (xdot, 0, 0), (x, 1, -1), 0, 0, False)  # ⟨ẋ→[−] ⇒ ↓x→[5]⟩
    add_dbn(agent, 4, CHANGE, (x, 1, 1), (ydot, 2, 0), 30, 3)         # ⟨↑x→[5] ⇒ ẏ→[+]⟩
    return agent


def test_nrp_needs_a_sufficiently_reliable_plan_for_the_antecedent():
    agent = nrp_agent(PARAMS)
    xdot, ydot = agent.table.index("x.dot"), agent.table.index("y.dot")
    add_dbn(agent, 5, CHANGE, (xdot, 2, 0), (ydot, 0, 0), 30, 3)      # ⟨ẋ→[+] ⇒ ẏ→[−]⟩
    agent._convert_dbns_to_plans(100)
    # motor antecedents convert; magnitude DBNs once a(ẋ, [±]) has a plan (same batch, since
    # they rank last: brel ⊥); DBNs 4 and 5 need a sufficiently reliable plan for their
    # antecedent, and the new plans have never been called
    assert plan_dbns(agent) == [0, 1, 2, 3]
    by_dbn = {pl.dbn_id: pl for pl in agent.plans.values()}
    by_dbn[3].ever_reliable = True                       # reaches x = 5 from above: wrong side
    agent._convert_dbns_to_plans(102)
    assert plan_dbns(agent) == [0, 1, 2, 3]
    by_dbn[2].ever_reliable = True                       # from below: ↑x → [5] is achievable
    agent._convert_dbns_to_plans(104)
    assert plan_dbns(agent) == [0, 1, 2, 3, 4]
    by_dbn[0].ever_reliable = True                       # a(ẋ, [+]) is now reliable
    agent._convert_dbns_to_plans(106)
    assert plan_dbns(agent) == [0, 1, 2, 3, 4, 5]


def test_nrp_ablation_converts_every_dbn_without_a_reliable_antecedent_plan():
    """§7.11.1's NRP condition (decision 97): criterion 1 of §6.2.2 is switched off, so the
    DBNs whose antecedent has no reliable plan (4 and 5 above) become plans in the first
    batch."""
    from qlap_runtime.qlap.params import Ablations

    agent = nrp_agent(PARAMS.replace(ablations=Ablations(nrp=True)))
    xdot, ydot = agent.table.index("x.dot"), agent.table.index("y.dot")
    add_dbn(agent, 5, CHANGE, (xdot, 2, 0), (ydot, 0, 0), 30, 3)      # ⟨ẋ→[+] ⇒ ẏ→[−]⟩
    agent._convert_dbns_to_plans(100)
    assert plan_dbns(agent) == [0, 1, 2, 3, 4, 5]
    assert not any(pl.ever_reliable for pl in agent.plans.values())


@pytest.mark.parametrize("targeted", [False, True])
def test_nrp_keeps_theta_sr_for_a_targeted_consequent(targeted):
    """Decision 75: a targeted consequent (§6.3: θ_SR = 0.25 for its own DBN) still needs a plan
    of the antecedent whose brel(o) was > 0.75 (criterion 1 of §6.2.2), not > 0.25."""
    from qlap_runtime.qlap.params import Ablations

    abl = Ablations(all_targeted=True) if targeted else Ablations(no_targeted=True)
    agent = nrp_agent(PARAMS.replace(ablations=abl))
    agent._convert_dbns_to_plans(100)
    assert plan_dbns(agent) == [0, 1, 2, 3]
    reach = next(pl for pl in agent.plans.values() if pl.dbn_id == 2)     # a(x, [5]) from below
    # 4 successes, 8 failures: fewer than the 5 successes brel needs (App. B.1)
    reach.cpt_s, reach.cpt_f = np.array([4.0]), np.array([8.0])
    agent._convert_dbns_to_plans(102)
    assert plan_dbns(agent) == [0, 1, 2, 3]
    # 6 and 10: brel(o) = 7/18 = 0.39, Pr(p > 0.25) = 1 − beta.cdf(0.25, 7, 11) = 0.893 ≥ 0.8
    reach.cpt_s, reach.cpt_f = np.array([6.0]), np.array([10.0])
    agent._convert_dbns_to_plans(104)
    assert not reach.ever_reliable                        # Pr(p > 0.75) = 0.0006
    assert plan_dbns(agent) == [0, 1, 2, 3]                 # targeted or not
    reach.ever_reliable = True
    agent._convert_dbns_to_plans(106)
    assert plan_dbns(agent) == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("targeted", [False, True])
def test_nrp_targeted_takes_a_plan_above_a_quarter_for_a_targeted_consequent(targeted):
    """``Params.nrp_targeted`` (decision 89, the reading decision 75 rejected): with the same
    plan of the antecedent as above (6 successes and 10 failures: Pr(p > 0.25) = 0.893 ≥ 0.8),
    the DBN of a targeted consequent becomes a plan; one not targeted still waits."""
    from qlap_runtime.qlap.params import Ablations

    abl = Ablations(all_targeted=True) if targeted else Ablations(no_targeted=True)
    agent = nrp_agent(PARAMS.replace(ablations=abl, nrp_targeted=True))
    agent._convert_dbns_to_plans(100)
    reach = next(pl for pl in agent.plans.values() if pl.dbn_id == 2)
    reach.cpt_s, reach.cpt_f = np.array([4.0]), np.array([8.0])     # < 5 successes: no brel
    agent._convert_dbns_to_plans(102)
    assert plan_dbns(agent) == [0, 1, 2, 3]
    reach.cpt_s, reach.cpt_f = np.array([6.0]), np.array([10.0])
    agent._convert_dbns_to_plans(104)
    assert not reach.ever_reliable
    assert plan_dbns(agent) == ([0, 1, 2, 3, 4] if targeted else [0, 1, 2, 3])


# --- the call list across a landmark batch (§5.2.2, §5.4.2) -------------------------------------


def test_a_landmark_batch_renumbers_the_running_call_list_and_keeps_q(trained):
    import copy

    from qlap_runtime.qlap.delta import AddLandmark, Delta

    agent, _ = copy.deepcopy(trained)
    agent.learning = True
    agent.clear_goal()
    world = ToyWorld(5.0)
    u = agent.table.index("u")
    # practise until a plan on u (a(ẋ, [±])) runs with its motor action below it
    t = agent.step_count + 1
    for _ in range(20):
        t = practising(agent, world, t)
        f0 = agent.call_list[0]
        if agent.plans[f0.plan_id].space.vars[-2:] == (u, agent.table.index("x.dot")) \
                and agent.call_list[-1].is_motor and f0.sub >= 0 and f0.sub_state >= 0:
            break
        agent.clear_goal()
        agent.call_list.clear()
        agent.mode = "idle"
    else:
        raise AssertionError("no call list with a plan on u")
    plan = agent.plans[f0.plan_id]
    old_q = plan.q.copy()
    old_sub, old_state = f0.sub, f0.sub_state
    old_act = plan.actions[old_sub]
    old_keys = [f.key for f in agent.call_list]
    assert agent.learner.perception.spaces[u].bounds(0)[1] < -0.29   # (−∞, −0.3…) is value 0
    # a landmark at −0.9 splits u's value 0; every value of u above it moves up by 2
    agent.learner.apply_delta(Delta(99, t - 1, t - 1, (AddLandmark(u, -0.9, -0.9, "dbn", t - 1),)))
    interrupts = agent.counters.call_list_interrupts
    full = {"x": world.x, **agent.motor}
    p = agent.learner.observe(t, full)
    agent._seen_applied = agent.learner.applied_count
    # The plans follow as in a lockstep batch: a compilation on a copy, applied at once.
    delta = agent.planning_copy(agent.learner.batch_copy()).compile_plans(t, t)
    agent.apply_plans(delta, p, agent._follow_landmarks())
    assert agent.counters.call_list_interrupts == interrupts           # not interrupted
    assert [f.key for f in agent.call_list] == \
        [(v, q + 2) if v == u else (v, q) for v, q in old_keys]
    assert plan.space.size_of(u) == 9
    # the frame's sub-action and state follow the new indices; the Q-value goes with them
    new_act = plan.actions[f0.sub]
    assert (new_act.var, new_act.role) == (old_act.var, old_act.role)
    assert new_act.value == old_act.value + (2 if old_act.var == u else 0)
    assert plan.q[f0.sub_state, f0.sub] == old_q[old_state, old_sub]
    agent._act(p)                                                       # and it runs on


def test_a_reliable_action_that_lost_its_plans_learns_again(tmp_path):
    """§6.2.1 restricts learning for a sufficiently reliable action only while it has a plan
    (decision 36): after its plans are removed, a(ẋ, [+]) leaves the learner's restricted set,
    so DBNs for it may be learned and converted again (here: at the next batch)."""
    agent, world = Agent(SPECS, PARAMS, seed=0), ToyWorld()
    run(agent, world, 0, 30_000)
    up = key_of(agent, "x.dot", 2)
    assert agent.actions[up].reliable and up in agent.learner.reliable_actions
    for pid in [pid for pid, p in agent.plans.items() if p.action == up]:
        agent._remove_plan(pid)
    agent._update_self()
    assert up not in agent.learner.reliable_actions
    run(agent, world, 30_000, 34_001)                  # two DBN batches
    assert any(p.action == up for p in agent.plans.values())


def nominal_goal_agent():
    """An agent with one plan for a nominal goal: a(b, true) by ⟨{}: ↑x→(8, +inf) ⇒ b→true⟩
    (its space is x and b, no direction of change); returns (agent, plan, x, b)."""
    from qlap_runtime.qlap.delta import AddDBN, AddLandmark, Delta
    from tests.qlap.toyworld import Spec

    specs = (Spec("u", "motor", -1.0, 1.0), Spec("x", "magnitude"),
             Spec("b", "nominal", values=("false", "true")))
    agent = Agent(specs, PARAMS, seed=1)
    for t in range(3):
        agent.step(t, {"x": 1.0, "b": 0.0})
    x, b = agent.table.index("x"), agent.table.index("b")
    agent.learner.apply_delta(Delta(1, 2, 2, (
        AddLandmark(x, 8.0, 8.0, "dbn", 2), AddDBN("change", (x, 2, 1), (b, 1, 0)))))
    agent.step(3, {"x": 1.0, "b": 0.0})
    dbn = next(d for d in agent.learner.dbns.values() if d.consequent.var == b)
    return agent, agent._add_plan(dbn, 3), x, b


def test_on_a_discontinuity_step_no_action_is_applicable():
    """docs/decisions.md 39: on the step after a jump no direction of change has a value, so a
    plan whose own state is known (here a(b, true) by ⟨{}: ↑x→(8, +inf) ⇒ b→true⟩, whose space
    is x and b) would still lead to sub-actions that cannot run: before this rule IAC chose
    such actions on these steps and their calls failed at once (core: 85 of 86 practice calls
    of a(T, true) from a 250k agent)."""
    agent, plan, x, b = nominal_goal_agent()
    assert plan is not None and set(plan.space.vars) == {x, b}
    agent.step(4, {"x": 2.0, "b": 0.0})
    p = agent._last_percept
    assert agent._usable_plans((b, 1), p, [plan]) == [plan]
    assert (b, 1) in agent._applicable(p)[0]
    agent.step(5, {"x": 5.0, "b": 0.0}, discontinuity=True)
    p = agent._last_percept
    assert p.discontinuity and plan.space.index_from_full(p.q) is not None
    assert agent._usable_plans((b, 1), p, [plan]) == []
    assert agent._applicable(p) == ([], [])


def test_a_sub_action_that_fails_as_it_is_called_gets_a_terminal_sarsa_update():
    """§5.2.2: "each time an action terminates, the agent performs a Sarsa update"; §5.5.2
    rule 4: a plan fails when the action its policy chose fails as it is called. a(b, true)'s
    only way, a(x, (8, +inf)), has no plan: its pair's Q moves to the failure's r' = 0,
    Q ← Q + α(0 − Q) = 0.8 Q, and nothing else changes (docs/decisions.md 40)."""
    agent, plan, x, b = nominal_goal_agent()
    agent.step(4, {"x": 2.0, "b": 0.0})
    p = agent._last_percept
    agent.learning = False                  # no Dyna sweep after the call: Sarsa alone
    before = plan.q.copy()
    assert agent._call((b, 1), p) == "fail" and agent.call_list == []
    changed = np.argwhere(plan.q != before)
    assert len(changed) == 1
    s, a = changed[0]
    assert plan.q[s, a] == pytest.approx(0.8 * before[s, a], abs=1e-12) and before[s, a] != 0.0
    assert (plan.actions[a].var, plan.actions[a].value) == (x, 2)    # a(x, (8, +inf))
    assert s == plan.space.index_from_full(p.q)
    agent.end_trial()                       # learning off: the trial's Sarsa is undone
    assert np.array_equal(plan.q, before)


def moving_up(trained, tmp_path) -> tuple[Agent, tuple[int, int], Percept]:
    """A copy of the trained agent two steps on, x having risen (ẋ = [+]): (agent, the key of
    a(ẋ, [+]), the percept)."""
    save_agent(trained[0], tmp_path / "ck")
    agent = load_agent(tmp_path / "ck")
    up = key_of(agent, "x.dot", 2)
    t = agent.step_count + 1
    agent.call_list, agent.goal = [], None
    agent.step(t, {"x": 5.0})
    agent.step(t + 1, {"x": 5.4})                     # x rose: ẋ = [+]
    p = agent._last_percept
    assert agent._achieved(up, p)
    return agent, up, p


def test_a_change_action_called_while_its_goal_holds_fails_at_its_call(trained, tmp_path):
    """§5.2.1 footnote 2 lets a plan's policy call a(ẋ, [+]) while ẋ = [+] already. Every state
    of that action's own plans with ẋ = [+] is a goal state with no action to choose, so the
    call fails on the step it is made and rel(a) counts one failure (docs/decisions.md 70:
    the reading that lets it succeed at the next step was measured, and made tasks worse)."""
    agent, up, p = moving_up(trained, tmp_path)
    plan = agent._usable_plans(up, p, agent._plan_groups().plans_of(up))[0]
    assert plan.model.goal[agent._plan_state(plan, p)]           # a goal state of its plan
    stats = agent.actions[up]
    calls, failures = stats.calls, stats.failures
    agent.call_list = []
    assert agent._call(up, p) == FAIL and agent.call_list == []
    assert (stats.calls, stats.failures) == (calls + 1, failures + 1)


def test_a_planning_copy_is_freed_as_soon_as_it_is_dropped(trained):
    """A compilation's copy of the agent and its batch learner (tens of MB in core) go when
    the compilation ends, without waiting for a full garbage collection: no plan of the copy
    keeps a method of the copy (docs/decisions.md 104: such a cycle kept up to seven copies
    alive at once in the embedded placement, 1.53× the synchronous loop's peak memory)."""
    agent, _ = trained
    assert agent.plans
    gc.collect()
    gc.disable()
    try:
        work = agent.learner.batch_copy()
        copy_ = agent.planning_copy(work, deep=True)
        t = agent.step_count
        delta = copy_.compile_plans(t, t)
        assert delta.ops                             # it compiled something
        assert all(p.space is not None for p in copy_.plans.values())
        gone_agent, gone_learner = weakref.ref(copy_), weakref.ref(work)
        del copy_, work
        assert gone_agent() is None and gone_learner() is None
    finally:
        gc.enable()


def test_the_executor_takes_the_models_its_compilation_built():
    """Decision 109: when the agent rebuilds a plan with the inputs its compilation's copy had
    (the synchronous loop, L = 0), it takes the transition model the copy built instead of
    building it again — and learns exactly what an agent that builds every model learns."""
    memo, own = Agent(SPECS, PARAMS, seed=0), Agent(SPECS, PARAMS, seed=0)
    own.model_memo = None
    run(memo, ToyWorld(), 0, 20_000)
    run(own, ToyWorld(), 0, 20_000)
    assert memo.plans and memo.model_memo is not None and memo.model_memo.hits > 0
    assert json.dumps(memo.knowledge()) == json.dumps(own.knowledge())
    assert sorted(memo.plans) == sorted(own.plans)
    for pid, plan in memo.plans.items():
        np.testing.assert_array_equal(plan.q, own.plans[pid].q)
    assert len(copy.deepcopy(memo).model_memo) == 0          # a checkpoint's copy: empty


def test_plan_reliable_dbn_counts_a_plan_whose_dbn_is_sufficiently_reliable():
    """``Params.plan_reliable == "dbn"`` (decision 105): criterion 1 of §6.2.2 takes a plan of
    the antecedent whose DBN is sufficiently reliable, though the plan's brel(o) never was; a
    magnitude plan whose DBN never was still does not count."""
    agent = nrp_agent(PARAMS.replace(plan_reliable="dbn"))
    xdot, ydot = agent.table.index("x.dot"), agent.table.index("y.dot")
    add_dbn(agent, 5, CHANGE, (xdot, 2, 0), (ydot, 0, 0), 30, 3)      # ⟨ẋ→[+] ⇒ ẏ→[−]⟩
    agent._convert_dbns_to_plans(100)
    # DBN 0's plan (a(ẋ, [+]); DBN 0 sufficiently reliable) is made first (rel(r) 41/44 =
    # 0.93 against DBN 5's 31/35), so DBN 5 converts in the same batch; DBN 4 waits for a
    # reliable plan reaching x = 5 from below (DBN 2 is not sufficiently reliable)
    assert plan_dbns(agent) == [0, 1, 2, 3, 5]
    assert not any(pl.ever_reliable for pl in agent.plans.values())
    agent.learner.dbns[2].ever_reliable = True
    agent._convert_dbns_to_plans(102)
    assert plan_dbns(agent) == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize("reading", ["o", "dbn"])
def test_plan_reliable_dbn_protects_a_plan_from_replacement(reading):
    """§6.2.2's slots: a plan "sufficiently reliable" is never replaced; with
    ``plan_reliable == "dbn"`` a plan whose DBN is sufficiently reliable counts (decision
    105), so a plan of rel(o) 5/40 keeps its slot; by brel(o) alone it is replaced."""
    agent = fresh_agent(SPECS, PARAMS.replace(max_plans_per_action=1, plan_reliable=reading))
    u, xdot = agent.table.index("u"), agent.table.index("x.dot")
    add_dbn(agent, 0, CHANGE, (u, 2, 0), (xdot, 2, 0), 20, 5)
    agent._convert_dbns_to_plans(100)
    (plan,) = agent.plans.values()
    plan.calls, plan.successes = 40, 5                   # rel(o) 0.15 (≥ 0.05: not removed)
    add_dbn(agent, 1, CHANGE, (u, 1, 0), (xdot, 2, 0), 40, 2)
    agent._convert_dbns_to_plans(200)
    assert plan_dbns(agent) == ([0] if reading == "dbn" else [1])


@pytest.mark.parametrize("reading", ["fail", "support"])
def test_an_achieved_change_action_called_by_a_plan_gives_its_motor_command(
        trained, tmp_path, reading):
    """§5.5 footnote 5 (``Params.achieved_call == "support"``, decision 106): a(ẋ, [+]) called
    by a plan while ẋ = [+] already runs its plan from the state with ẋ at [0], which commands
    u into the range that moves x up; the other reading (decision 70) fails at the call."""
    agent, up, p = moving_up(trained, tmp_path)
    agent.params = agent.params.replace(achieved_call=reading)
    u = agent.table.index("u")
    agent.motor["u"] = 0.0
    parent = Frame(key_of(agent, "x", 0), p.step)     # the calling plan's frame
    agent.call_list = [parent]
    status = agent._call(up, p)
    if reading == "fail":
        assert status == FAIL and agent.call_list == [parent]
        return
    assert status == RUN
    keys = [f.key[0] for f in agent.call_list]
    assert keys[:2] == [parent.key[0], up[0]] and keys[-1] == u
    assert agent.motor["u"] > 0.29                    # u → (0.3…, +∞): the value that moves x up


def test_a_dbn_deleted_for_its_age_is_learned_again_while_its_contingency_holds():
    """§6.2.3 deletes a DBN neither sufficiently reliable nor a plan after ``dbn_max_age``
    steps; the text does not forbid learning its pair again, and the pair statistics still
    hold the contingency, so the next batch learns it anew, with a new age (docs/decisions.md
    119: keeping it out for good, or until new evidence, both lost hit_floor)."""
    import worlds
    from qlap_runtime.agent_run import params_for_world, run_agent

    world = worlds.make("core2d")
    params = params_for_world(world, Params(babble_steps=1500, dbn_period=500,
                                            landmark_period=1000, dbn_max_age=1000))
    try:
        agent, _ = run_agent(world, 6000, 3, params=params)
        before = {(d.antecedent, d.consequent): d.created
                  for d in agent.learner.dbns.values() if d.kind == CHANGE}
        agent, _ = run_agent(world, 4000, 3, params=params, agent=agent)
    finally:
        world.close()
    after = {(d.antecedent, d.consequent): d.created
             for d in agent.learner.dbns.values() if d.kind == CHANGE}
    again = {pair: (before[pair], created) for pair, created in after.items()
             if pair in before and created > before[pair]}
    # Deleted at the first batch past 1,000 steps of age, learned at the batch after.
    assert again and all(new - old >= 1500 for old, new in again.values())


def test_a_landmark_inside_a_magnitude_gives_its_new_values_plans_in_the_same_compilation(
        trained):
    """§5.3: a magnitude action has a plan from each side. A landmark inside x's quantity
    space renumbers the values above it; the plans' goals follow their DBNs before the
    compilation converts DBNs, so the new values' magnitude DBNs get their plans at once.
    With the old numbers the neighbours' plans stood for the new values and refused them until
    the next batch (docs/decisions.md 120)."""
    from qlap_runtime.qlap.delta import AddLandmark, Delta

    agent, world = copy.deepcopy(trained)
    x = agent.table.index("x")
    space = agent.learner.perception.spaces[x]
    lo, hi = space.bounds(2)                        # a bounded interval inside the space
    assert np.isfinite(lo) and np.isfinite(hi)
    mid = (lo + hi) / 2
    t = agent.step_count + 1

    def sides() -> set[tuple[int, int]]:
        return {(pl.goal.value, pl.goal.direction) for pl in agent.plans.values()
                if pl.kind == MAGNITUDE and pl.goal.var == x}

    size = old_size = space.size
    assert sides() == {(v, 1) for v in range(1, size)} | {(v, -1) for v in range(size - 1)}
    agent.learner.apply_delta(Delta(99, t - 1, t - 1, (AddLandmark(x, mid, mid, "dbn", t - 1),)))
    p = agent.learner.observe(t, {"x": world.x, **agent.motor})
    agent._seen_applied = agent.learner.applied_count
    delta = agent.planning_copy(agent.learner.batch_copy()).compile_plans(t, t)
    agent.apply_plans(delta, p, agent._follow_landmarks())
    size = agent.learner.perception.spaces[x].size
    assert size == old_size + 2
    assert sides() == {(v, 1) for v in range(1, size)} | {(v, -1) for v in range(size - 1)}


def test_the_stuck_rule_counts_ten_steps_from_the_call(trained):
    """§5.2.3: stuck when none of the plan's or self variables "change in 10 timesteps",
    counted from the call: a frame records the state it was called in, so a state that never
    changes is stuck 10 steps after the call (it was 11: the first look found nothing
    recorded and started the count again)."""
    agent, _ = copy.deepcopy(trained)
    agent.learning = False
    agent.call_list.clear()
    p = agent._last_percept
    xdot = agent.table.index("x.dot")
    key = next(k for k in ((xdot, 2), (xdot, 0)) if p.q[xdot] != k[1])
    assert agent._call(key, p) != FAIL
    f = agent.call_list[0]
    plan = agent.plans[f.plan_id]
    assert f.last_change == p.step
    later = [dataclasses.replace(p, step=p.step + d) for d in (1, 9, 10)]
    assert not agent._stuck_or_out_of_time(f, plan, later[0])
    assert not agent._stuck_or_out_of_time(f, plan, later[1])
    assert agent._stuck_or_out_of_time(f, plan, later[2])


def test_knowledge_followed_without_a_plan_delta_recounts_the_second_order_cpts(trained):
    """Under the realtime clock a batch's landmarks may arrive before its plan delta; the
    plans are then rebuilt here (``_follow_knowledge``), and their second-order CPTs must be
    laid out in the new values of C_o, as a plan delta's recount lays them (§5.4), or rel(o, s)
    reads, and calls are counted in, the wrong cells."""
    from qlap_runtime.qlap.delta import AddLandmark, Delta

    agent, world = copy.deepcopy(trained)
    x = agent.table.index("x")
    plan = next(pl for pl in agent.plans.values() if x in pl.context_o)
    space = agent.learner.perception.spaces[x]
    lo, hi = space.bounds(2)
    t = agent.step_count + 1
    agent.learner.apply_delta(Delta(99, t - 1, t - 1,
                                    (AddLandmark(x, (lo + hi) / 2, (lo + hi) / 2, "dbn", t - 1),)))
    p = agent.learner.observe(t, {"x": world.x, **agent.motor})
    agent._follow_knowledge(p, agent._follow_landmarks())
    sizes = agent._sizes()
    cells = int(np.prod([sizes[v] for v in plan.context_o]))
    assert len(plan.cpt_s) == len(plan.cpt_f) == cells == space.size
    assert plan.cpt_s.sum() + plan.cpt_f.sum() == len(plan.stored_calls()[1])


def test_a_landmark_that_splits_the_goals_value_drops_the_goal_and_says_why(trained):
    """Goal mode with learning on (the UI's ``g``): a landmark inside the goal's value leaves
    three values, none the one asked for, so the goal is dropped with a note rather than
    silently narrowed to the lower part; a goal above the split is renumbered (+2) and kept
    (§4.4; docs/decisions.md 121)."""
    from qlap_runtime.qlap.delta import AddLandmark, Delta

    agent, world = copy.deepcopy(trained)
    x = agent.table.index("x")
    space = agent.learner.perception.spaces[x]
    lo, hi = space.bounds(2)
    assert np.isfinite(lo) and np.isfinite(hi) and space.size > 4
    t = agent.step_count + 1

    def split_value_2(at: int) -> None:
        s = agent.learner.perception.spaces[x]
        lo, hi = s.bounds(2)
        mid = (lo + hi) / 2
        agent.learner.apply_delta(Delta(99 + at, at - 1, at - 1,
                                        (AddLandmark(x, mid, mid, "dbn", at - 1),)))
        agent.learner.observe(at, {"x": world.x, **agent.motor})
        agent._seen_applied = agent.learner.applied_count
        agent._follow_landmarks()

    agent.set_goal(x, 4)                                 # above the split: renumbered
    split_value_2(t)
    assert agent.goal == (x, 6) and agent.goal_dropped is None
    agent.set_goal(x, 2)                                 # the split value itself: dropped
    split_value_2(t + 1)
    assert agent.goal is None and agent.mode == "idle"
    step, why = agent.goal_dropped
    parts = [agent.learner.value_label(x, q) for q in (2, 3, 4)]
    assert why == (f"goal on x dropped at step {step + 1}: a new landmark split its value "
                   f"into {', '.join(parts)}; give the goal again")


def test_a_plan_removed_below_rel_o_005_is_made_again_from_its_dbn():
    """§6.2.2 removes a plan whose rel(o) falls below 0.05; its DBN stays, and the conversion
    of the same compilation may make it a plan again, with fresh statistics (the text does
    not keep a DBN from becoming a plan again; the reading that does was measured and not
    kept, docs/decisions.md 122)."""
    from qlap_runtime.qlap.plan_delta import RemovePlan

    agent = nrp_agent(PARAMS)
    agent._convert_dbns_to_plans(100)
    old = next(pl for pl in agent.plans.values() if pl.dbn_id == 0)
    old.calls, old.successes = 30, 0                     # rel(o) = 1/32 < 0.05 (prior 1)
    assert old.stats_removed(agent.params)
    copy_ = agent.planning_copy(agent.learner.batch_copy())
    delta = copy_.compile_plans(102, 102)
    removed = [op.plan_id for op in delta.ops if isinstance(op, RemovePlan)]
    assert removed == [old.id]
    again = [pl for pl in copy_.plans.values() if pl.dbn_id == 0]
    assert len(again) == 1 and again[0].id != old.id and again[0].calls == 0
