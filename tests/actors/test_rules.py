"""Rules on well-formed messages (issue 13, item 1): a message that decodes but cannot be one of
the run's own — an unknown motor, a motor out of range, a step outside the lockstep window, a
delta or qstate naming an unknown variable, a ``save`` outside the run directory — is counted,
logged and dropped; it never reaches the physics or the algorithm."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest
import trio

import worlds
from actors.convert import REQUEST_FILES, BadRequest, compile_request
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import RejectionCounter, TrioSubscriber
from qlap_runtime.bus.qrecord import QRecord, encode_record
from qlap_runtime.bus.schema import Control, DeltaMsg, Motor, PlanRequest, QState, Sense, encode
from qlap_runtime.placements.launcher import run_embedded_async
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.inbox import MAX_PENDING_BYTES, StepInbox
from qlap_runtime.runtime.rules import delta_rule, motor_rule, op_problem, planreq_rule
from tests.actors.test_lockstep import STEPS, context, sync_knowledge

PARAMS = Params(babble_steps=1500, dbn_period=500, landmark_period=1000)
FORGE_AT = tuple(range(100, 1100, 100))


def bogus_record(t: int) -> QRecord:
    """A well-formed ``qstate`` record of a table the world does not have."""
    return encode_record(t, b"zz\x00h_x", np.array([0.5, 1.0]), np.array([1, 1]))


def forger(escape: str):
    """At sense(t) for t in FORGE_AT, puts rule-breaking messages on every lockstep topic."""

    async def task(session, ctx):
        k = lambda topic: keys.key(ctx.run_id, topic)            # noqa: E731
        bad_dbn = {"version": 1, "computed_at": 500, "apply_at": 500,
                   "ops": [["add_dbn", "change", [999, 1, 0], [0, 1, 0], []]]}
        off_step = {"version": 1, "computed_at": 123, "apply_at": 123, "ops": [["refresh"]]}
        counter = RejectionCounter("forger")
        with TrioSubscriber(session, k("sense"), counter=counter) as sub:
            done = set()
            async for batch in sub:
                for r in batch:
                    t = r.msg.step
                    if t not in FORGE_AT or t in done:
                        continue
                    done.add(t)
                    session.put(k("motor"), encode(Motor(t, {"u_x": 0.1, "u_bogus": 1.0})))
                    session.put(k("motor"), encode(Motor(t, {"u_x": 1e300})))
                    session.put(k("motor"), encode(Motor(t + 50, {"u_x": 0.1})))
                    session.put(k("delta/dbn"), encode(DeltaMsg("dbn", bad_dbn)))
                    session.put(k("delta/dbn"), encode(DeltaMsg("dbn", off_step)))
                    session.put(k("qstate"), encode(QState(t, {"zz": 1}, (), {})))
                    # binary records (decision 98): of another table, and cut
                    session.put(k("qstate"), bogus_record(t).payload)
                    session.put(k("qstate"), bogus_record(t).payload[:-1])
                    session.put(k("sense"), encode(Sense(t + 100, {"h_x": 0.0})))
                    session.put(k("control"), encode(Control("save", {"path": escape})))
                    # files where the planner shares the executor's process (no files there)
                    session.put(k("planreq"), encode(PlanRequest(
                        t + 400, {name: "!!" for name in REQUEST_FILES})))
                if len(done) == len(FORGE_AT):
                    return

    return task


def test_rule_breaking_messages_are_counted_and_change_nothing(tmp_path):
    out = tmp_path / "run"
    escape = str(tmp_path / "escaped")
    ctx = context(out, "core2d", PARAMS, 3, "t-rules")
    summary = trio.run(lambda: run_embedded_async(ctx, extra=(forger(escape),)))
    assert summary["steps"] == STEPS
    n = len(FORGE_AT)
    actors = summary["actors"]
    assert actors["world"]["rejected"] == 3 * n          # unknown motor, 1e300, window
    assert actors["perception"]["rejected"] == 3 * n     # sense window, two bad deltas
    # qstate unknown var (JSON, a record), a cut record, two bad deltas
    assert actors["contingency"]["rejected"] == 5 * n
    assert actors["landmarks"]["rejected"] == 5 * n
    assert actors["executor"]["rejected"] == 6 * n       # ... and the save outside the run
    assert actors["planner"]["rejected"] == 3 * n        # the two bad deltas, the planreq
    assert summary["rejected_messages"] == 25 * n
    assert not (tmp_path / "escaped").exists()
    got = (out / "knowledge.json").read_text()
    assert json.loads(got)["dbns"]
    assert got == sync_knowledge("core2d", PARAMS, seed=3)


def test_motor_rule_names_the_problem():
    w = worlds.make("core2d")
    try:
        rule = motor_rule(w.variables)
    finally:
        w.close()
    assert rule(Motor(3, {"u_x": 0.5})) is None
    assert "unknown motor 'u_z'" in rule(Motor(3, {"u_z": 0.5}))
    assert "outside" in rule(Motor(3, {"u_x": 1e300}))


def test_delta_rule_and_ops():
    rule = delta_rule(PARAMS.replace(batch_lag=200), n_vars=10)
    ok = {"version": 1, "computed_at": 1000, "apply_at": 1200,
          "ops": [["refresh"], ["set_k", 3], ["add_dbn", "change", [1, 1, 0], [2, 0, 1], [3]],
                  ["add_landmark", 4, 0.5, 0.6, "dbn", 1000, 7, [1, 1, 0], [2]]]}
    assert rule(DeltaMsg("landmarks", ok)) is None
    assert "not a batch step" in rule(DeltaMsg("landmarks", {**ok, "computed_at": 500,
                                                              "apply_at": 700}))
    assert "apply_at 1000" in rule(DeltaMsg("dbn", {**ok, "apply_at": 1000}))
    assert op_problem(["add_landmark", 10, 0.5, 0.6, "event", 5, None, None, None], 10)
    assert op_problem(["set_context", 1, [0, 12]], 10)
    assert op_problem(["set_k", 10**7], 10)


def test_pending_future_messages_are_bounded_in_bytes():
    inbox = StepInbox(sub=None, first=0, counter=RejectionCounter("t"), key="k", window=5000)
    size = 6_800_000                                      # the 6.8 MB sense messages
    kept = sum(inbox.add(Sense(t, {}), size) for t in range(1, 21))
    assert kept == MAX_PENDING_BYTES // size == 9
    assert inbox.counter.total == 11
    assert inbox.pending_bytes == 9 * size
    inbox.drop(1)
    assert inbox.pending_bytes == 8 * size


def test_planreq_rule_and_a_request_that_holds_no_agent(tmp_path):
    """A planreq must fit the placement (in memory beside the executor, files elsewhere); one
    whose files are not an agent's checkpoint is a BadRequest, raised before any compilation
    (the planner counts it and takes the request again: StepInbox.again)."""
    files = {name: "" for name in REQUEST_FILES}
    beside, apart = planreq_rule(REQUEST_FILES, True), planreq_rule(REQUEST_FILES, False)
    assert beside(PlanRequest(500, local=True)) is None
    assert apart(PlanRequest(500, files)) is None
    assert "does not share" in apart(PlanRequest(500, local=True))
    assert "shares" in beside(PlanRequest(500, files))
    assert beside(PlanRequest(500, last=True)) is None and apart(PlanRequest(7, rejected=True)) \
        is None
    with pytest.raises(BadRequest, match=r"planreq\(500\): Error"):          # not base64
        compile_request(PlanRequest(500, {name: "!!" for name in REQUEST_FILES}), [], 0)
    junk = {name: base64.b64encode(b"not a checkpoint").decode() for name in REQUEST_FILES}
    with pytest.raises(BadRequest, match=r"planreq\(500\)"):
        compile_request(PlanRequest(500, junk), [], 0)
    with pytest.raises(BadRequest, match="no agent was handed over .* step 500"):
        compile_request(PlanRequest(500, local=True), [], 0, run_id="nobody")


def test_a_step_inbox_takes_a_step_again():
    inbox = StepInbox(None, first=10)  # type: ignore[arg-type]
    assert inbox.add(PlanRequest(10, local=True)) and inbox.add(PlanRequest(11, local=True))
    assert trio.run(inbox.get, 10).step == 10 and inbox.next == 11
    assert not inbox.add(PlanRequest(10, local=True))              # consumed: a duplicate
    inbox.again(10)
    assert inbox.next == 10 and inbox.add(PlanRequest(10, files={"x": ""}))
    assert trio.run(inbox.get, 10).files == {"x": ""} and inbox.next == 12 - 1
