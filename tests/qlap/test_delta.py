"""Typed delta operations: the JSON lists of the wire and of checkpoints unchanged, every field of
a malformed operation named; the public state of Perception, ModelLearner and Agent."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import pytest

from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.checkpoint import load_learner, save_learner
from qlap_runtime.qlap.delta import (
    OP_NAMES,
    AddDBN,
    AddLandmark,
    DeleteDBN,
    Delta,
    Refresh,
    SetContext,
    SetK,
    op_from_json,
)
from qlap_runtime.qlap.perception import Perception
from qlap_runtime.qlap.quantity import Landmark
from qlap_runtime.qlap.variables import Event
from tests.qlap.toyworld import SPECS, babble_stream

# Each operation and its JSON list as the tuples of the untyped operations gave it (the form of
# recorded runs and checkpoints).
ROUND_TRIPS = [
    (Refresh(), ["refresh"]),
    (SetK(7), ["set_k", 7]),
    (AddDBN("change", Event(3, 2, 0), Event(7, 1, 0), (4, 9)),
     ["add_dbn", "change", [3, 2, 0], [7, 1, 0], [4, 9]]),
    (AddDBN("magnitude", Event(0, 4, 1), Event(2, 3, -1)),
     ["add_dbn", "magnitude", [0, 4, 1], [2, 3, -1], []]),
    (SetContext(12, (4, 9)), ["set_context", 12, [4, 9]]),
    (SetContext(12, ()), ["set_context", 12, []]),
    (DeleteDBN(12), ["delete_dbn", 12]),
    (AddLandmark(5, 0.25, 0.75, "event", 4000),
     ["add_landmark", 5, 0.25, 0.75, "event", 4000, None, None, None]),
    (AddLandmark(5, -1.5, -1.25, "dbn", 6000, 12, Event(5, 2, 0), None),
     ["add_landmark", 5, -1.5, -1.25, "dbn", 6000, 12, [5, 2, 0], None]),
    (AddLandmark(5, 300.0, 310.5, "dbn", 6000, 3, None, (1, 5)),
     ["add_landmark", 5, 300.0, 310.5, "dbn", 6000, 3, None, [1, 5]]),
]


@pytest.mark.parametrize(("op", "wire"), ROUND_TRIPS)
def test_each_operation_round_trips_through_its_unchanged_json_list(op, wire):
    assert op.to_json() == wire
    assert json.dumps(op.to_json()) == json.dumps(wire)
    assert op_from_json(wire) == op
    assert op_from_json(json.loads(json.dumps(wire))) == op     # through text, as on the bus
    assert type(op_from_json(tuple(wire))) is type(op)          # tuples read as lists
    assert hash(op) == hash(op_from_json(wire))
    with pytest.raises(dataclasses.FrozenInstanceError):
        op.x = 1                                                 # type: ignore[attr-defined]


def test_every_operation_has_a_round_trip_above():
    assert sorted({type(op).NAME for op, _ in ROUND_TRIPS}) == sorted(OP_NAMES)


def test_lists_from_callers_become_events_and_tuples():
    op = AddDBN("change", [3, 2, 0], [7, 1, 0], [4])             # type: ignore[arg-type]
    assert op == AddDBN("change", Event(3, 2, 0), Event(7, 1, 0), (4,))
    assert isinstance(op.antecedent, Event) and op.context == (4,)
    lm = AddLandmark(5, 0.5, 0.5, "dbn", 10, 2, [5, 0, 0], [1])  # type: ignore[arg-type]
    assert lm.antecedent == Event(5, 0, 0) and lm.context == (1,)


def test_a_delta_keeps_its_json_form_and_reads_a_stored_one():
    text = ('{"version": 4001, "computed_at": 2000, "apply_at": 2500, "ops": [["refresh"], '
            '["set_k", 3], ["add_dbn", "change", [1, 1, 0], [2, 0, 1], [3]], '
            '["add_landmark", 4, 0.5, 0.625, "dbn", 2000, 7, [1, 1, 0], null]]}')
    d = Delta.from_json(json.loads(text))
    assert d.ops == (Refresh(), SetK(3), AddDBN("change", Event(1, 1, 0), Event(2, 0, 1), (3,)),
                     AddLandmark(4, 0.5, 0.625, "dbn", 2000, 7, Event(1, 1, 0)))
    assert json.dumps(d.to_json()) == text
    assert (d.version, d.computed_at, d.apply_at, d.applied) == (4001, 2000, 2500, False)


GOOD_LANDMARK = ["add_landmark", 4, 0.5, 0.6, "dbn", 1000, 7, [1, 1, 0], [2]]


def landmark(i: int, value) -> list:
    out = list(GOOD_LANDMARK)
    out[i] = value
    return out


MALFORMED = [
    ([], "not a non-empty list"),
    ("refresh", "not a non-empty list"),
    (["nope"], "unknown delta operation 'nope'"),
    ([3], "unknown delta operation 3"),
    (["refresh", 1], "refresh: 0 field(s) expected, got 1"),
    (["set_k"], "set_k: 1 field(s) expected, got 0"),
    (["set_k", 0], "set_k: k must be an integer ≥ 1, got 0"),
    (["set_k", 2.5], "set_k: k must be an integer ≥ 1, got 2.5"),
    (["set_k", True], "set_k: k must be an integer ≥ 1, got True"),
    (["add_dbn", "bogus", [1, 1, 0], [2, 0, 1], []],
     "add_dbn: kind must be one of 'change', 'magnitude', got 'bogus'"),
    (["add_dbn", "change", [1, 1], [2, 0, 1], []],
     "add_dbn: antecedent must be an event [var, value, direction], got [1, 1]"),
    (["add_dbn", "change", ["u_x", 1, 0], [2, 0, 1], []],
     "add_dbn: antecedent.var must be an integer ≥ 0, got 'u_x'"),
    (["add_dbn", "change", [1, 1, 0], [2, -1, 1], []],
     "add_dbn: consequent.value must be an integer ≥ 0, got -1"),
    (["add_dbn", "change", [1, 1, 0], [2, 0, 5], []],
     "add_dbn: consequent.direction must be -1, 0 or 1, got 5"),
    (["add_dbn", "change", [1, 1, 0], [2, 0, 1], None],
     "add_dbn: context must be a list of variable indexes, got None"),
    (["add_dbn", "change", [1, 1, 0], [2, 0, 1], [3, "x"]],
     "add_dbn: context[1] must be an integer ≥ 0, got 'x'"),
    (["set_context", -1, [2]], "set_context: dbn_id must be an integer ≥ 0, got -1"),
    (["set_context", 3, 4], "set_context: context must be a list of variable indexes, got 4"),
    (["delete_dbn", "3"], "delete_dbn: dbn_id must be an integer ≥ 0, got '3'"),
    (["delete_dbn", 3, 4], "delete_dbn: 1 field(s) expected, got 2"),
    (landmark(1, -1), "add_landmark: var must be an integer ≥ 0, got -1"),
    (landmark(2, math.nan), "add_landmark: lb must be a finite number, got nan"),
    (landmark(3, math.inf), "add_landmark: ub must be a finite number, got inf"),
    (landmark(3, "0.6"), "add_landmark: ub must be a finite number, got '0.6'"),
    (landmark(4, "user"), "add_landmark: source must be one of 'event', 'dbn', got 'user'"),
    (landmark(5, 1000.0), "add_landmark: step must be an integer ≥ 0, got 1000.0"),
    (landmark(6, -2), "add_landmark: dbn_id must be an integer ≥ 0, got -2"),
    (landmark(7, [1, 1]), "add_landmark: antecedent must be an event"),
    (landmark(7, [1, 1, 2]), "add_landmark: antecedent.direction must be -1, 0 or 1, got 2"),
    (landmark(8, [2.5]), "add_landmark: context[0] must be an integer ≥ 0, got 2.5"),
    (GOOD_LANDMARK[:5], "add_landmark: 8 field(s) expected, got 4"),
]


@pytest.mark.parametrize(("item", "message"), MALFORMED)
def test_a_malformed_operation_is_refused_naming_its_field(item, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        op_from_json(item)
    with pytest.raises(ValueError, match="delta operation"):
        Delta.from_json({"version": 1, "computed_at": 0, "apply_at": 0,
                         "ops": [["refresh"], item]})


def test_the_good_landmark_above_is_well_formed():
    assert op_from_json(GOOD_LANDMARK) == AddLandmark(4, 0.5, 0.6, "dbn", 1000, 7,
                                                      Event(1, 1, 0), (2,))


# ---------------------------------------------------------------------------------------------
# Public state
# ---------------------------------------------------------------------------------------------
def learner_at(steps: int, params: Params | None = None) -> ModelLearner:
    learner = ModelLearner(SPECS, params or Params())
    for t, obs in babble_stream(steps, 1):
        learner.observe(t, obs)
    return learner


def test_perception_state_round_trip():
    learner = learner_at(3000)
    per = learner.perception
    per.add_landmark(learner.table.index("x"), Landmark(4.0, 4.25, 2999, "event"))
    meta, arrays = per.to_state()
    assert list(meta) == ["spaces", "hist_len", "hist_head", "steps_seen", "all_seen"]
    assert list(arrays) == ["prev_x", "prev_q", "hist_x", "hist_q"]
    assert meta["steps_seen"] == 3000 and meta["hist_len"] == min(3000, per.hist_x.shape[0])
    other = Perception(learner.table, learner.params)
    other.load_state(json.loads(json.dumps(meta)), {k: v.copy() for k, v in arrays.items()})
    meta2, arrays2 = other.to_state()
    assert meta2 == meta
    for k, v in arrays.items():
        np.testing.assert_array_equal(arrays2[k], v)
        assert arrays2[k].dtype == v.dtype
    assert other.events.sizes == per.events.sizes
    x = per.vector({"u": 0.5, "x": 4.1})
    np.testing.assert_array_equal(other.perceive(3000, x.copy()).q, per.perceive(3000, x).q)


def test_learner_state_is_the_open_activations_and_survives_a_checkpoint(tmp_path):
    learner = learner_at(8567)          # after step 8566: one change and one magnitude DBN open
    state = learner.to_state()
    assert list(state) == ["expiry", "mag_active"]
    assert len(state["expiry"]) == 1 and len(state["mag_active"]) == 1
    for t, dbn_id, i in state["expiry"]:
        assert t > learner.step and 0 <= i < len(learner.dbns[dbn_id].pending)
    save_learner(learner, tmp_path)
    assert load_learner(tmp_path).to_state() == state
    again = ModelLearner(SPECS, Params())
    again.dbns = load_learner(tmp_path).dbns
    again.load_state(json.loads(json.dumps(state)))
    assert again.to_state() == state


def test_agent_state_and_restored_plans(tmp_path):
    from qlap_runtime.qlap.agent import Agent
    from qlap_runtime.qlap.checkpoint import load_agent, save_agent

    agent = Agent(SPECS, Params(), seed=0)
    for t, obs in babble_stream(600, 2):
        agent.step(t, {"x": obs["x"]})
    assert agent.to_state() == {"seen_applied": agent.learner.applied_count,
                                "pending_plans": []}
    assert agent.last_percept is not None and agent.last_percept.step == 599
    save_agent(agent, tmp_path)
    assert json.loads((tmp_path / "agent.json").read_text())["seen_applied"] == \
        agent.learner.applied_count
    loaded = load_agent(tmp_path)
    assert loaded.to_state() == agent.to_state()
    loaded.load_state({"seen_applied": 41})
    assert loaded.to_state() == {"seen_applied": 41, "pending_plans": []}
