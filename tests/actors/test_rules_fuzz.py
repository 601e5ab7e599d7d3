"""Forged-but-well-formed messages drawn by hypothesis (issue 13): random members of every
rule-breaking family — unknown motor names, motor values outside the range, motors and senses
for steps outside the lockstep window, deltas naming a variable the run does not have or
computed at a step that is not a batch step, qstates naming unknown variables, ``save`` paths
outside the run directory — put on their topics during an embedded run. Every one is counted by
every actor that subscribes to its topic, and the knowledge equals the unfuzzed sync run's."""

from __future__ import annotations

import functools

import trio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import RejectionCounter, TrioSubscriber
from qlap_runtime.bus.schema import Control, DeltaMsg, Motor, QState, Sense, encode
from qlap_runtime.placements.launcher import run_embedded_async
from qlap_runtime.qlap import Params
from tests.actors.test_lockstep import context, sync_knowledge

PARAMS = Params(babble_steps=1500, dbn_period=500, landmark_period=1000)
MOTORS = {"u_x", "u_y"}
N_VARS = 1000                                             # far above any world's table

# Which actors count a forgery of each kind (tests/actors/test_rules.py has the same accounting).
READERS = {"motor": ("world",), "sense": ("perception",),
           "delta": ("perception", "contingency", "landmarks", "planner", "executor"),
           "qstate": ("contingency", "landmarks", "executor"), "save": ("executor",)}

names = st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=8)
forgery = st.one_of(
    st.tuples(st.just("motor"), st.just("name"),
              names.filter(lambda n: n not in MOTORS), st.floats(-1.0, 1.0)),
    st.tuples(st.just("motor"), st.just("value"), st.sampled_from(sorted(MOTORS)),
              st.one_of(st.floats(1e13, 1e300), st.floats(-1e300, -1e13))),
    st.tuples(st.just("motor"), st.just("window"), st.integers(40, 400), st.just(0.0)),
    st.tuples(st.just("sense"), st.just("window"), st.integers(100, 400), st.just(0.0)),
    st.tuples(st.just("delta"), st.just("var"), st.integers(N_VARS, 10**6), st.just(0.0)),
    st.tuples(st.just("delta"), st.just("step"),
              st.integers(1, 5).map(lambda i: 500 * i + 123), st.just(0.0)),
    st.tuples(st.just("qstate"), st.just("var"), names.map(lambda n: "zz_" + n), st.just(0.0)),
    st.tuples(st.just("save"), st.just("path"), names, st.just(0.0)),
)


def message(kind: str, what: str, arg, value: float, t: int, escape_dir: str):
    """(topic, encoded message) of one forgery at sense(t)."""
    if kind == "motor":
        if what == "name":
            return "motor", Motor(t, {"u_x": 0.1, arg: value})
        if what == "value":
            return "motor", Motor(t, {arg: value})
        return "motor", Motor(t + arg, {"u_x": 0.1})
    if kind == "sense":
        return "sense", Sense(t + arg, {"h_x": 0.0})
    if kind == "delta":
        if what == "var":
            body = {"version": 1, "computed_at": 500, "apply_at": 500,
                    "ops": [["add_dbn", "change", [arg, 1, 0], [0, 1, 0], []]]}
        else:
            body = {"version": 1, "computed_at": arg, "apply_at": arg, "ops": [["refresh"]]}
        return "delta/dbn", DeltaMsg("dbn", body)
    if kind == "qstate":
        return "qstate", QState(t, {arg: 1}, (), {})
    return "control", Control("save", {"path": f"{escape_dir}/{arg}"})


@functools.cache
def unfuzzed() -> str:
    return sync_knowledge("core2d", PARAMS, seed=3)


@settings(max_examples=3, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(forgery, min_size=8, max_size=20))
def test_random_forgeries_are_counted_and_change_nothing(tmp_path_factory, forgeries):
    tmp = tmp_path_factory.mktemp("fuzz")
    out, escape_dir = tmp / "run", tmp / "escaped"
    at = {100 + 50 * i: f for i, f in enumerate(forgeries)}   # one forgery per sense step

    async def forger(session, ctx):
        counter = RejectionCounter("forger")
        with TrioSubscriber(session, keys.key(ctx.run_id, "sense"), counter=counter) as sub:
            done: set[int] = set()
            async for batch in sub:
                for r in batch:
                    t = r.msg.step
                    if t in at and t not in done:
                        done.add(t)
                        topic, msg = message(*at[t], t, str(escape_dir))
                        session.put(keys.key(ctx.run_id, topic), encode(msg))
                if len(done) == len(at):
                    return

    ctx = context(out, "core2d", PARAMS, 3, "t-fuzz")
    summary = trio.run(lambda: run_embedded_async(ctx, extra=(forger,)))
    expected = dict.fromkeys(("world", "perception", "contingency", "landmarks", "planner",
                              "executor"), 0)
    for kind, *_ in forgeries:
        for actor in READERS[kind]:
            expected[actor] += 1
    assert {a: summary["actors"][a]["rejected"] for a in expected} == expected
    assert not escape_dir.exists()
    assert (out / "knowledge.json").read_text() == unfuzzed()
