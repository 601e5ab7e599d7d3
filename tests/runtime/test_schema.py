"""Bus messages: round trips, and rejection of anything malformed with the key in the error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from qlap_runtime.bus import keys
from qlap_runtime.bus.schema import (
    MESSAGE_TYPES,
    TOPIC_TYPES,
    ActionInfo,
    AgentStatus,
    BatchContext,
    CallList,
    Control,
    DeltaMsg,
    IACChoice,
    Knowledge,
    KnowledgeCounters,
    LandmarkInfo,
    MessageError,
    Motor,
    PlanDeltaMsg,
    PlanInfo,
    PlanRequest,
    QState,
    Rejected,
    Sense,
    Stats,
    WorldView,
    decode,
    encode,
    json_schema,
)
from qlap_runtime.qlap.delta import AddDBN, AddLandmark, Delta, SetK
from qlap_runtime.qlap.mdp import NOT_APPLICABLE
from qlap_runtime.qlap.plan_delta import AddPlan, PlanContexts, PlanDelta, Rebuild, RemovePlan
from qlap_runtime.qlap.variables import Event

EXAMPLES = {
    "sense": Sense(7, {"hand_x": 0.25, "hand_y": -1.5}),
    "qstate": QState(7, {"hand_x": 2, "T": 0}, (("hand_x", 2, 1), ("T", 0, 0))),
    "motor": Motor(7, {"u_x": 300.0, "u_UG": 0.0}),
    "batchctx": BatchContext(1999, ((5, 2), (7, 0)), (0, 3, 12)),
    "delta/dbn": DeltaMsg.of("dbn", Delta(3, 4000, 4500, (
        SetK(4), AddDBN("change", Event(0, 2, 0), Event(3, 1, 1), ())))),
    "delta/landmarks": DeltaMsg.of("landmarks", Delta(1, 4000, 4500, (
        AddLandmark(3, 0.1, 0.2, "event", 4000),))),
    "delta/plans": PlanDeltaMsg.of(PlanDelta(4000, 4500, (
        RemovePlan(3), PlanContexts(((5, (2, 7)),)),
        AddPlan(9, 12, np.array([[0.5, NOT_APPLICABLE], [1.25, 0.0]])), Rebuild(5)))),
    "planreq": PlanRequest(4000, {"agent.json": "e30="}),
    "calllist": CallList(7, ("a(hand_x,2)", "a(T,1)")),
    "iac": IACChoice(7, "a(T,1)", 0.4, 12, False, {"a(T,1)": 0.4, "a(hand_x,2)": 0.1}),
    "stats": Stats(7, "world", 2100.5, waits=1, late_ticks=2, missed_ticks=0,
                   rejected=Rejected(3, {"qlap/r/sense": 3}, "qlap/r/sense: bad")),
    "control": Control("goal", {"var": "T", "value": 1}),
    "knowledge": Knowledge(
        7, 4, (ActionInfo("a(ḣ_x, [+])", "h_x.dot", "[+]", 2, 0.8, 10, 8, True, 0.2,
                          (0.5, 0.8), (PlanInfo(0, 3, "⟨{}: u_x→(0.3, +∞) ⇒ ḣ_x→[+]⟩",
                                                "change", -1.0, 0.5, ("h_x",), 0.7, 9, 6),)),),
        {"h_x": (LandmarkInfo("0.25", 4000, "event"),)}, KnowledgeCounters(dbns=3, plans=1),
        {"h_x.dot": ("[-]", "[0]", "[+]")}, ("h_x.dot",)),
    "world": WorldView(7, "core2d", "..H..\n.....", {"h_x": 0.5}, {"u_x": 1.0},
                       {"h_x": "(0.25, +inf)"}),
    "status": AgentStatus(7, 2100.0, "practice", paused=True, goal="a(ḣ_x, [+])"),
}


def test_every_topic_has_an_example_and_a_type():
    assert set(EXAMPLES) == set(keys.TOPICS) == set(TOPIC_TYPES)
    for topic, msg in EXAMPLES.items():
        assert type(msg) is TOPIC_TYPES[topic]


@pytest.mark.parametrize("topic", sorted(EXAMPLES))
def test_round_trip(topic):
    msg = EXAMPLES[topic]
    payload = encode(msg)
    assert payload == json.dumps(json.loads(payload), separators=(",", ":"),
                                 ensure_ascii=False).encode()  # compact
    assert decode(f"qlap/r1/{topic}", payload) == msg


def test_utf8_names_survive():
    msg = Sense(1, {"Δx": 1.0})
    assert "Δx".encode() in encode(msg)
    assert decode("qlap/r/sense", encode(msg)) == msg


def test_float_fields_accept_integers_and_delta_unwraps():
    assert decode("qlap/r/motor", b'{"step":1,"values":{"u":3},"version":1}') == Motor(
        1, {"u": 3.0})
    d = decode("qlap/r/delta/dbn", encode(EXAMPLES["delta/dbn"]))
    assert d.to_delta().ops[0] == SetK(4)


BAD = [
    (b"\xff\xfe", "not UTF-8 JSON"),
    (b"{not json", "not UTF-8 JSON"),
    (b'{"step":1,"values":{"a":NaN},"version":1}', "NaN"),
    (b'{"step":1,"values":{"a":Infinity},"version":1}', "Infinity"),
    (b'{"step":1,"values":{"a":1e999},"version":1}', "finite"),
    (b'[1,2]', "JSON object"),
    (b'{"step":1,"values":{},"version":2}', "unknown version 2"),
    (b'{"step":1,"values":{}}', "version"),
    (b'{"step":1,"version":1}', "missing field 'values'"),
    (b'{"step":1,"values":{},"version":1,"extra":0}', "unknown field"),
    (b'{"step":"1","values":{},"version":1}', "step must be an integer"),
    (b'{"step":1.5,"values":{},"version":1}', "step must be an integer"),
    (b'{"step":true,"values":{},"version":1}', "step must be an integer"),
    (b'{"step":1,"values":{"a":"x"},"version":1}', "values['a'] must be a number"),
    (b'{"step":1,"values":[1],"version":1}', "values must be an object"),
]


@pytest.mark.parametrize(("payload", "reason"), BAD)
def test_malformed_sense_is_rejected_with_its_key(payload, reason):
    with pytest.raises(MessageError) as e:
        decode("qlap/r9/sense", payload)
    assert e.value.key_expr == "qlap/r9/sense"
    assert str(e.value).startswith("qlap/r9/sense: ")
    assert reason in str(e.value)


def test_type_specific_rules():
    with pytest.raises(MessageError, match="qlap/r/delta/plans: .*step"):
        decode("qlap/r/delta/plans", encode(EXAMPLES["delta/dbn"]))
    with pytest.raises(MessageError, match="qlap/r/delta/dbn: .*unknown field"):
        decode("qlap/r/delta/dbn", encode(EXAMPLES["delta/plans"]))
    with pytest.raises(MessageError, match="add_plan: q.values"):
        decode("qlap/r/delta/plans", b'{"step":1,"delta":{"computed_at":1,"apply_at":2,'
                                     b'"ops":[["add_plan",0,1,{"shape":[1,1],"na":"AA==",'
                                     b'"values":""}]]},"version":1}')
    bad_op = b'{"kind":"dbn","delta":{"version":1,"computed_at":0,"apply_at":0,' \
             b'"ops":[["rm_rf"]]},"version":1}'
    with pytest.raises(MessageError, match="unknown delta operation"):
        decode("qlap/r/delta/dbn", bad_op)
    with pytest.raises(MessageError, match="command must be one of"):
        decode("qlap/r/control", b'{"command":"explode","args":{},"version":1}')
    with pytest.raises(MessageError, match=r"events\[0\] must be an array of 3"):
        decode("qlap/r/qstate", b'{"step":1,"values":{},"events":[["a",1]],"version":1}')
    with pytest.raises(MessageError, match="rejected.total must be an integer"):
        decode("qlap/r/stats", b'{"step":1,"rejected":{"total":"x"},"version":1}')


def test_unknown_keys_are_rejected():
    for key in ("qlap/r/nope", "other/r/sense", "qlap/r/alive/world", "qlap"):
        with pytest.raises(MessageError) as e:
            decode(key, encode(EXAMPLES["sense"]))
        assert e.value.key_expr == key


def test_nan_is_refused_on_encode_too():
    with pytest.raises(MessageError, match="cannot encode"):
        encode(Sense(1, {"a": float("nan")}))


def test_json_schemas_document_every_field():
    for cls in MESSAGE_TYPES:
        s = json_schema(cls)
        assert s["type"] == "object" and s["additionalProperties"] is False
        assert s["properties"]["version"]["enum"] == [1]
        for name, prop in s["properties"].items():
            assert prop.get("description"), f"{cls.__name__}.{name} has no docstring"
    q = json_schema(QState)
    assert q["required"] == ["step", "values"]
    assert q["properties"]["events"]["items"]["prefixItems"][0] == {"type": "string"}


def test_messages_are_frozen():
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        EXAMPLES["sense"].step = 3  # type: ignore[misc]
