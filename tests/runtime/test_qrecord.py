"""``qstate`` as a binary record (docs/decisions.md 98): exact round trips of real percepts,
rejected and discontinuous steps included; forged and cut records rejected and counted, over
real Zenoh sessions on loopback."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trio

import worlds
from actors.convert import QStateCodec
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import (
    FRAMED,
    Publisher,
    RejectionCounter,
    TrioSubscriber,
    frame,
    unframe,
)
from qlap_runtime.bus.qrecord import (
    HEAD,
    MAGIC,
    QRecord,
    encode_record,
    encode_rejected,
    payload_bytes,
    payload_text,
)
from qlap_runtime.bus.schema import MessageError, QState, decode, encode, qstate_of
from qlap_runtime.qlap import ModelLearner, Params
from qlap_runtime.qlap.perception import InvalidObservation, Perception
from qlap_runtime.runtime.rules import qstate_rule

KEY = keys.key("test-run", "qstate")


def core_steps(n: int) -> tuple[list, list[dict], list]:
    """``n`` steps of core2d with random motors: its variables, observations (motors
    included) and the world's discontinuity flags."""
    world = worlds.make("core2d")
    specs, rng = world.variables, np.random.default_rng(3)
    motors = [v.name for v in specs if str(getattr(v.kind, "value", v.kind)) == "motor"]
    obs, rows, jumps = world.reset(seed=1), [], []
    for _ in range(n):
        applied = {m: float(rng.uniform(-1, 1)) for m in motors}
        rows.append({**obs, **applied})
        jumps.append(bool(world.discontinuity))
        obs = world.step(applied)
    world.close()
    return specs, rows, jumps


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def test_records_of_real_percepts_round_trip_exactly_and_learn_as_the_sync_learner():
    """Every step's record, decoded as a consumer decodes it, gives the percept's arrays bit
    for bit (NaN where a value is not known yet), its events and its discontinuity; a
    follower learning from the records perceives what the synchronous learner perceives;
    ``qstate_of`` is the JSON message of the same percept."""
    specs, rows, jumps = core_steps(120)
    jumps[40] = jumps[77] = True                        # a teleport's discontinuity
    params = Params()
    sync, follower = ModelLearner(specs, params), ModelLearner(specs, params)
    follower.auto_batches, follower.follower = False, True
    per = Perception(sync.table, params)                # the perception actor's
    codec, rule = QStateCodec(per.table), qstate_rule(QStateCodec(per.table).names)
    seen_nan = seen_event = 0
    for t, (row, jump) in enumerate(zip(rows, jumps, strict=True)):
        p = per.perceive(t, per.vector(row), discontinuity=jump)
        rec = codec.record(p)
        assert rec.payload[:3] == MAGIC and encode(rec) is rec.payload
        got = decode(KEY, rec.payload)
        assert type(got) is QRecord and got == rec and rule(got) is None
        assert got.step == t and got.discontinuity is jump and got.rejected == ""
        assert same(got.x, p.x) and same(got.q, p.q)
        assert [tuple(e) for e in got.events.tolist()] == [tuple(e) for e in p.events]
        assert qstate_of(got) == codec.message(p)
        seen_nan += int(np.isnan(got.x).sum())
        seen_event += len(p.events)
        mine = follower.observe_percept(codec.percept(got))
        theirs = sync.observe(t, row, discontinuity=jump)
        assert same(mine.x, theirs.x) and same(mine.q, theirs.q)
        assert mine.events == theirs.events and same(mine.event_ids, theirs.event_ids)
    assert seen_nan > 0 and seen_event > 0              # both cases were exercised


def test_a_rejected_observation_travels_as_its_reason():
    """A NaN observation is rejected by perception; its record carries the reason and nothing
    else, round-trips, and is the JSON message the perception actor wrote before."""
    specs, rows, _ = core_steps(3)
    per = Perception(ModelLearner(specs, Params()).table, Params())
    bad = dict(rows[2])
    bad[next(iter(bad))] = math.nan
    per.perceive(0, per.vector(rows[0]))
    with pytest.raises(InvalidObservation) as exc:
        per.perceive(1, per.vector(bad))
    rec = QStateCodec(per.table).rejected(1, str(exc.value))
    got = decode(KEY, rec.payload)
    assert got.rejected == str(exc.value) and "non-finite" in got.rejected
    assert got.n == 0 and len(got.x) == 0 and len(got.events) == 0
    assert qstate_of(got) == QState(1, {}, (), {}, rejected=str(exc.value))
    assert qstate_rule(QStateCodec(per.table).names)(got) is None
    assert len(rec.payload) == HEAD.size + len(str(exc.value).encode())


def forged() -> dict[str, bytes]:
    """A valid record (3 variables, one event) and what a forger or a cut could make of it."""
    blob = b"a\x00b\x00c"
    good = encode_record(5, blob, np.array([1.5, math.nan, -2.0]), np.array([2, -1, 0]),
                         [(0, 2, 1)]).payload
    n_at = HEAD.size + len(blob)

    def patch(at: int, raw: bytes) -> bytes:
        return good[:at] + raw + good[at + len(raw):]

    return {
        "cut": good[:-5], "padded": good + b"\x00", "header only": good[:HEAD.size - 1],
        "version": patch(3, b"\x07"), "flags": patch(4, b"\x10"),
        "infinite x": patch(n_at, np.array([math.inf]).tobytes()),
        "q below -1": patch(n_at + 24, np.array([-5], dtype="<i8").tobytes()),
        "event var": patch(n_at + 48, np.array([3], dtype="<i4").tobytes()),
        "event direction": patch(n_at + 56, np.array([2], dtype="<i4").tobytes()),
        "names": patch(HEAD.size, b"\xff"),
        "rejected with variables": patch(4, b"\x01"),
    }


def test_forged_or_cut_records_are_rejected_with_a_reason_and_counted():
    counter = RejectionCounter("test")
    good = forged()
    assert decode(KEY, encode_record(5, b"a\x00b\x00c", np.array([1.5, math.nan, -2.0]),
                                     np.array([2, -1, 0]), [(0, 2, 1)]).payload).step == 5
    for what, payload in good.items():
        with pytest.raises(MessageError, match="invalid qstate record") as exc:
            decode(KEY, payload)
        assert exc.value.key_expr == KEY, what
        assert counter.decode(KEY, payload) is None
    assert counter.total == len(good) and counter.by_key == {KEY: len(good)}
    with pytest.raises(MessageError, match="truncated or padded"):
        decode(KEY, good["cut"])


def test_the_rule_takes_only_records_of_the_table():
    """A well-formed record of another table (other names, or another order) or with a
    qualitative value out of range is not one of the run's."""
    rule = qstate_rule(("a", "b", "c"))
    x, q = np.array([0.0, 1.0, 2.0]), np.array([0, 1, 2])
    assert rule(encode_record(1, b"a\x00b\x00c", x, q)) is None
    assert "unknown variable(s) ['zz']" in rule(encode_record(1, b"a\x00b\x00zz", x, q))
    assert "table's order" in rule(encode_record(1, b"c\x00b\x00a", x, q))
    assert "out of range" in rule(encode_record(1, b"a\x00b\x00c", x, np.array([0, 1, 10_000])))
    assert rule(encode_rejected(1, "NaN")) is None


def test_a_snapshot_keeps_records_as_text_and_gives_them_back():
    rec = encode_record(9, b"a", np.array([0.25]), np.array([1]), [(0, 1, 0)], True)
    text = payload_text(rec.payload)
    assert text.startswith("base64:") and payload_bytes(text) == rec.payload
    js = encode(QState(9, {"a": 1}))
    assert payload_text(js) == js.decode() and payload_bytes(js.decode()) == js


async def test_records_go_to_another_session_in_framed_bundles_and_a_cut_one_is_counted(
        two_clients, run_id):
    """Held records (which may hold newlines) reach another session as one framed bundle,
    message by message and bit for bit; a forged framed bundle whose last part is cut gives
    its whole parts, and the cut one is counted, never raised."""
    here, there = two_clients
    key = keys.key(run_id, "qstate")
    blob = b"a\x00b"
    recs = [encode_record(t, blob, np.array([t + 0.5, 10.0]), np.array([t % 3, 10]),  # 10: "\n"
                          [(1, 1, -1)] * (t % 2), discontinuity=t == 3) for t in range(6)]
    assert any(b"\n" in r.payload for r in recs)
    counter = RejectionCounter("remote")
    with TrioSubscriber(there, key, counter=counter) as remote, \
            Publisher(here, run_id, "qstate") as pub:
        with trio.fail_after(10):
            while not remote.received:          # the other session's subscription is routed
                pub.put(encode_rejected(-1, "warm-up"))
                await trio.sleep(0.05)
        await trio.sleep(0.2)
        remote.receive_nowait()
        for r in recs:
            assert pub.hold(r)
        pub.flush()
        assert pub.bundles == 1
        got: list = []
        with trio.fail_after(10):
            while len(got) < len(recs):
                got += [r.msg for r in await remote.receive_batch()]
        assert got == recs and got[3].discontinuity and len(got[1].events) == 1
        assert counter.total == 0
        data = frame([recs[0].payload, recs[1].payload])
        here.put(key, data[:-3], attachment=FRAMED)     # a forged bundle, cut
        with trio.fail_after(10):
            while counter.total < 1:
                got = [r.msg for r in await remote.receive_batch()]
                assert got in ([], [recs[0]])
        assert counter.total == 1 and "truncated" in counter.last_error


def test_unframe_gives_what_a_forged_or_cut_bundle_holds_and_never_raises():
    parts = [b"abc", b"", b"\n\x00xyz"]
    data = frame(parts)
    assert unframe(data) == parts
    assert unframe(data[:-2]) == [b"abc", b"", b"\n\x00x"]     # the last one cut
    assert unframe(data + b"zz") == [*parts, b"zz"]            # bytes left over: one more
    assert unframe(data[:5]) == [data[:5]]                      # lengths cut: the whole
    assert unframe(b"\xff\xff\xff\xff") == [b"\xff\xff\xff\xff"] and unframe(b"") == [b""]
