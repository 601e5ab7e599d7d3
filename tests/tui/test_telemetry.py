"""Telemetry from a real agent: valid, NaN-free bus messages; cadence rules."""

from __future__ import annotations

import json

import numpy as np
import pytest

from qlap_runtime import telemetry
from qlap_runtime.bus.schema import decode, encode
from qlap_runtime.qlap.agent import Agent
from tests.tui.conftest import FAST


@pytest.fixture(scope="module")
def trained():
    import worlds

    world = worlds.make("core2d")
    agent = Agent(world.variables, FAST, seed=0)
    obs = world.reset(seed=0)
    for t in range(7000):
        obs = world.step(agent.step(t, obs))
    return agent, world


def round_trip(topic: str, msg):
    payload = encode(msg)
    json.loads(payload)  # strict JSON (encode refuses NaN)
    assert decode(f"qlap/r/{topic}", payload) == msg
    return msg


def test_knowledge_snapshot_lists_actions_with_plans_in_the_reference_notation(trained):
    agent, _ = trained
    k = round_trip("knowledge", telemetry.knowledge_msg(agent))
    assert k.step == agent.step_count
    with_plans = [a for a in k.actions if a.plans]
    assert len(with_plans) >= 1
    assert k.counters.plans == len(agent.plans) == sum(len(a.plans) for a in k.actions)
    for a in with_plans:
        assert a.label.startswith("a(") and ".dot" not in a.label
        assert 0.0 <= a.rel <= 1.0 and a.weight >= 0.0
        for p in a.plans:
            assert p.label.startswith("⟨") and "⇒" in p.label and ".dot" not in p.label
            assert p.brel == -1.0 or 0.0 <= p.brel <= 1.0
    assert any("\u0307" in a.label for a in k.actions)        # ḣ / ẏ: the dot notation
    assert k.counters.landmarks == sum(lm.source != "initial" for lms in k.landmarks.values()
                                       for lm in lms)
    assert set(k.values) == {v.name for v in agent.table if v.kind.value != "motor"}


def test_call_list_world_status_and_iac(trained):
    agent, world = trained
    cl = round_trip("calllist", telemetry.call_list_msg(agent))
    assert list(cl.actions) == [telemetry.pretty(x) for x in agent.call_list_labels()]
    w = round_trip("world", telemetry.world_msg(agent, world))
    assert w.world == "core2d" and "H" in w.text and set(w.values) == set(world.observation)
    s = round_trip("status", telemetry.status_msg(agent, steps_per_s=float("nan"), paused=True))
    assert s.steps_per_s == 0.0 and s.paused and s.mode == agent.mode
    after = agent.iac_log[-3].step
    msgs = [round_trip("iac", m) for m in telemetry.iac_msgs(agent, after)]
    assert [m.step for m in msgs] == [c.step for c in list(agent.iac_log)[-2:]]
    for m in msgs:
        assert m.babbling == (m.action == "")
        if not m.babbling:
            assert np.isclose(sum(m.weights.values()), 1.0)


def test_cadence_limits_display_rate_and_sends_knowledge_on_change():
    c = telemetry.Cadence(display_hz=10, knowledge_every=250, knowledge_min_s=0.25,
                          knowledge_max_s=2.0)
    assert c.display_due(0.0) and not c.display_due(0.05) and c.display_due(0.11)
    assert c.knowledge_due(0.0, 0, (1,))
    assert not c.knowledge_due(0.1, 10, (2,))                 # too soon, even if changed
    assert c.knowledge_due(0.3, 20, (2,))                     # changed
    assert not c.knowledge_due(0.6, 100, (2,))                # same, < 250 steps
    assert c.knowledge_due(0.9, 270, (2,))                    # 250 steps later
    assert c.knowledge_due(3.0, 270, (2,))                    # paused: every 2 s
    assert (telemetry.pretty("⟨{}: u_x→(0.3, +inf) ⇒ h_x.dot→[+]⟩")
            == "⟨{}: u_x→(0.3, +∞) ⇒ h\u0307_x→[+]⟩")


def test_pretty_writes_infinity_zero_and_minus_one_way():
    assert telemetry.pretty("(-inf, -0)") == "(−∞, 0)"
    assert telemetry.pretty("a(u_x, -0)") == "a(u_x, 0)"
    assert telemetry.pretty("[-0.05, 0.05]") == "[\u22120.05, 0.05]"   # not a zero
    assert telemetry.pretty("(1e-05, -0.5)") == "(1e-05, \u22120.5)"  # an exponent keeps "-"
    assert telemetry.pretty("u_x→(-inf, -292.655)") == "u_x→(−∞, \u2212292.655)"
    assert telemetry.pretty("h_x.dot→[-]") == "h\u0307_x→[-]"        # a change value's name
    assert telemetry.pretty("x_RL-1") == "x_RL-1"
    assert telemetry.pretty("-0.000") == "0.000"


def test_the_world_view_holds_one_step_and_the_status_counts_from_minus_one():
    """Raw values, the motor command that led to them and the qualitative values agree: they
    are what the agent perceives at its next step (a copy of it takes that step)."""
    import copy

    import worlds

    world = worlds.make("core2d")
    agent = Agent(world.variables, FAST, seed=0)
    obs = world.reset(seed=0)
    assert telemetry.status_msg(agent, steps_per_s=0.0, paused=False).step == -1
    checked = 0
    for t in range(3000):
        obs = world.step(agent.step(t, obs, discontinuity=bool(world.discontinuity)))
        if t % 250 != 249:
            continue
        w = telemetry.world_msg(agent, world)
        assert w.step == agent.step_count == t and w.text.startswith(f"core2d t={t + 1} ")
        assert w.motor == agent.motor and w.values == dict(world.observation)
        twin = copy.deepcopy(agent)
        twin.step(t + 1, dict(obs), discontinuity=bool(world.discontinuity))
        p = twin._last_percept
        seen = {v.name: twin.learner.value_label(v.index, int(p.q[v.index]))
                for v in twin.table if p.q[v.index] >= 0}
        assert w.qualitative == seen
        for name, value in w.motor.items():          # motor rows: raw and qualitative agree
            space = agent.learner.perception.spaces[agent.table.index(name)]
            assert w.qualitative[name] == space.label(space.value_of(value))
        checked += 1
    assert checked == 12


def test_iac_msgs_after_any_step_are_those_of_a_full_scan(trained):
    """The choices after a step, found from the newest back (the display's 10 Hz scan)."""
    agent, _ = trained
    steps = [c.step for c in agent.iac_log]
    assert len(steps) >= 3 and steps == sorted(steps)
    for after in (-1, steps[0] - 1, steps[0], steps[len(steps) // 2], steps[-2], steps[-1]):
        msgs = telemetry.iac_msgs(agent, after)
        assert [m.step for m in msgs] == [s for s in steps if s > after]
