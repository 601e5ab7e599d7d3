"""Bad input on every subscribed key of a running agent: counted, never fatal, never learned."""

from __future__ import annotations

import json

import trio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from qlap_runtime.bus import keys
from qlap_runtime.placements.launcher import run_embedded_async
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext
from tests.actors.test_lockstep import sync_knowledge

TOPICS = ("sense", "qstate", "motor", "delta/dbn", "delta/landmarks", "control")
PARAMS = Params(babble_steps=1000, dbn_period=500, landmark_period=1000)
STEPS = 1500

# Payloads that are not valid for the topic they are put on: random bytes, broken or non-object
# JSON, NaN, and valid messages of *another* topic's type.
WRONG_TYPED = [
    b'{"step": 1, "values": {"u_x": "high"}, "version": 1}',              # wrong value type
    b'{"step": "3", "values": {}, "events": [], "version": 1}',
    b'{"step": 2, "values": {"x": NaN}, "version": 1}',
    b'{"kind": "dbn", "delta": {"version": 1}, "version": 1}',
    b'{"command": "explode", "args": {}, "version": 1}',
    b'{"step": 1, "values": {}, "version": 99}',
    b"[1, 2, 3]", b"null", b"\xff\xfe\x00", b"",
]
payloads = st.one_of(st.binary(max_size=64), st.sampled_from(WRONG_TYPED))
messages = st.lists(st.tuples(st.sampled_from(TOPICS), payloads), min_size=5, max_size=40)


def fuzzer(batch):
    async def task(session, ctx):
        for i, (topic, payload) in enumerate(batch):
            session.put(keys.key(ctx.run_id, topic), payload)
            await trio.sleep(0.001 * (i % 3))
    return task


@settings(max_examples=3, deadline=None, suppress_health_check=list(HealthCheck))
@given(batch=messages)
def test_garbage_on_every_key_is_rejected_and_changes_nothing(tmp_path_factory, batch):
    out = tmp_path_factory.mktemp("fuzz")
    ctx = RunContext(f"fuzz-{abs(hash(repr(batch))) % 10**8}", "core2d", STEPS, 2, PARAMS,
                     out=out)
    summary = trio.run(lambda: run_embedded_async(ctx, extra=(fuzzer(batch),)))
    assert summary["steps"] == STEPS                      # no actor died
    assert summary["rejected_messages"] >= 1              # each one counted
    got = (out / "knowledge.json").read_text()
    assert got == expected_knowledge()                    # and nothing of it was learned


_EXPECTED: list[str] = []


def expected_knowledge() -> str:
    if not _EXPECTED:
        import worlds
        from qlap_runtime.agent_run import params_for_world

        w = worlds.make("core2d")
        params = params_for_world(w, PARAMS)
        w.close()
        import tests.actors.test_lockstep as lock

        saved = lock.STEPS
        lock.STEPS = STEPS
        try:
            _EXPECTED.append(sync_knowledge("core2d", params, seed=2))
        finally:
            lock.STEPS = saved
    return _EXPECTED[0]


def test_wrong_typed_examples_are_invalid_on_their_topics():
    from qlap_runtime.bus.schema import MessageError, decode

    for topic in TOPICS:
        for payload in WRONG_TYPED:
            try:
                decode(keys.key("r", topic), payload)
            except MessageError:
                continue
            raise AssertionError(f"{payload!r} decoded on {topic}")
    assert json.loads(WRONG_TYPED[0])["values"]["u_x"] == "high"
