"""The trio <-> Zenoh bridge over real sessions (embedded; a router and clients on loopback)."""

from __future__ import annotations

import logging

import pytest
import trio
import zenoh

from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import (
    AliveWatcher,
    Publisher,
    RejectionCounter,
    StateQueryable,
    TrioInbox,
    TrioSubscriber,
    declare_alive,
    fetch,
)
from qlap_runtime.bus.config import client_config
from qlap_runtime.bus.schema import CallList, DeltaMsg, Motor, QState, Sense, decode, encode
from qlap_runtime.qlap.delta import Delta

N_BURST = 20_000


async def test_burst_of_20000_with_block_arrives_whole_and_in_order(two_clients, run_id):
    sub_session, pub_session = two_clients
    counter = RejectionCounter("test")
    got: list[int] = []
    with TrioSubscriber(sub_session, keys.key(run_id, "sense"), counter=counter) as sub, \
            Publisher(pub_session, run_id, "sense") as pub:
        assert pub.congestion == zenoh.CongestionControl.BLOCK
        with trio.fail_after(10):
            await pub.wait_matched()

        def burst() -> None:  # the publisher runs flat out in its own thread
            for i in range(N_BURST):
                pub.put(Sense(i, {"x": i * 0.5, "y": -1.0}))

        batches = 0
        with trio.fail_after(60):
            async with trio.open_nursery() as nursery:
                nursery.start_soon(trio.to_thread.run_sync, burst)
                while len(got) < N_BURST:
                    batch = await sub.receive_batch()
                    batches += 1
                    got.extend(r.msg.step for r in batch)
    assert got == list(range(N_BURST))
    assert counter.total == 0
    assert batches < N_BURST  # wake-ups are coalesced


async def test_malformed_messages_are_counted_and_do_not_stop_the_subscriber(
        embedded, run_id, caplog):
    counter = RejectionCounter("perception")
    key = keys.key(run_id, "sense")
    garbage = [b"\x00\xff", b"{}", b'{"step":1,"values":{"x":NaN},"version":1}',
               b'{"step":1,"values":{},"version":99}', b"[]"]
    with caplog.at_level(logging.WARNING, logger="qlap.bus"), \
            TrioSubscriber(embedded, key, counter=counter) as sub, \
            Publisher(embedded, run_id, "sense") as pub:
        for i, g in enumerate(garbage):
            pub.put_raw(g)
            pub.put(Sense(i, {"x": 1.0}))
        got = []
        with trio.fail_after(5):
            while len(got) < len(garbage):
                got.extend(await sub.receive_batch())
    assert [r.msg.step for r in got] == list(range(len(garbage)))
    assert counter.total == len(garbage)
    assert counter.by_key == {key: len(garbage)}
    assert "got array" in counter.snapshot().last_error
    assert "unknown version 99" in caplog.text
    assert f"rejected message #5 on {key}" in caplog.text


async def test_publisher_refuses_the_wrong_type_and_picks_congestion_control(embedded, run_id):
    with Publisher(embedded, run_id, "motor") as motor, \
            Publisher(embedded, run_id, "calllist") as calllist:
        assert motor.congestion == zenoh.CongestionControl.BLOCK
        assert calllist.congestion == zenoh.CongestionControl.DROP
        with pytest.raises(TypeError, match="carries Motor"):
            motor.put(Sense(1, {}))
        motor.put(Motor(1, {"u": 0.0}))
        calllist.put(CallList(1, ()))


async def test_liveliness_shows_an_actor_appear_and_disappear(router_endpoint, run_id):
    with zenoh.open(client_config(router_endpoint)) as watcher_session, \
            AliveWatcher(watcher_session, run_id) as watcher:
        with trio.fail_after(10):
            with zenoh.open(client_config(router_endpoint)) as actor_session, \
                    declare_alive(actor_session, run_id, "world"):
                assert await watcher.wait_until(lambda alive: "world" in alive) == {"world"}
            # the actor's session closed, as when its process dies
            await watcher.wait_until(lambda alive: "world" not in alive)


async def test_late_joiner_fetches_current_state(embedded, run_id):
    key = keys.key(run_id, "delta/landmarks")
    deltas = [DeltaMsg.of("landmarks", Delta(v, 4000 * v, 4000 * v, ())) for v in (1, 2, 3)]
    with StateQueryable(embedded, key) as state:
        for d in deltas:
            state.append(key, d)
        with trio.fail_after(10):
            replies = await fetch(embedded, f"qlap/{run_id}/delta/**")
        assert [r.msg for r in replies] == deltas
        state.set(key, deltas[-1])
        with trio.fail_after(10):
            replies = await fetch(embedded, key)
        assert [r.msg for r in replies] == [deltas[-1]]


async def test_inbox_wakes_once_per_burst_from_another_thread():
    inbox: TrioInbox[int] = TrioInbox()

    def produce() -> None:
        for i in range(1000):
            inbox.push(i)
        inbox.close()

    await trio.to_thread.run_sync(produce)
    got: list[int] = []
    while batch := await inbox.get_batch():
        got.extend(batch)
    assert got == list(range(1000))


async def test_subscriber_iteration_ends_when_closed(embedded, run_id, autojump_clock):
    sub = TrioSubscriber(embedded, keys.key(run_id, "sense"))
    batches = []

    async def consume() -> None:
        async for batch in sub:
            batches.append(batch)

    async with trio.open_nursery() as nursery:
        nursery.start_soon(consume)
        await trio.sleep(1)
        sub.close()
    assert batches == []


async def test_a_message_reaches_its_own_sessions_subscribers_within_put_and_once(
        embedded, run_id):
    """LocalRoutes: on a peer session (the embedded placement's) Zenoh runs Python callbacks on
    a thread of its own, so an in-process hop cost a thread hand-over and a trio wake-up; a
    Publisher now hands its message to the TrioSubscribers of its session during ``put``. A
    lockstep topic then goes out on Zenoh only to other sessions (decision 73): a raw
    subscriber of the same session gets nothing, and no zenoh put is made while no other
    session listens. A display topic still reaches a raw subscriber of the session, and the
    TrioSubscriber drops the tagged second copy."""
    key = keys.key(run_id, "sense")
    raw: list[bytes] = []
    with TrioSubscriber(embedded, key) as sub, Publisher(embedded, run_id, "sense") as pub:
        handle = embedded.declare_subscriber(key, lambda s: raw.append(s.payload.to_bytes()))
        assert pub.matched                      # the TrioSubscriber
        for t in range(3):
            before = sub.received
            pub.put(Sense(t, {"x": 1.0}))
            assert sub.received == before + 1          # delivered within put
        await trio.sleep(0.5)
        assert raw == [] and pub.skipped == 3
        assert [r.msg.step for r in sub.receive_nowait()] == [0, 1, 2]     # once each
        handle.undeclare()
    key = keys.key(run_id, "calllist")
    with TrioSubscriber(embedded, key) as sub, Publisher(embedded, run_id, "calllist") as pub:
        handle = embedded.declare_subscriber(key, lambda s: raw.append(s.payload.to_bytes()))
        for t in range(3):
            pub.put(CallList(t, ()))
        await trio.sleep(0.5)                  # the raw and the tagged copies arrive meanwhile
        assert len(raw) == 3
        assert len(sub.receive_nowait()) == 3  # once each
        handle.undeclare()


async def test_a_session_that_subscribes_mid_run_gets_the_lockstep_messages_from_then_on(
        two_clients, run_id):
    """Decision 73: with nobody outside the session, a lockstep topic is not put on Zenoh; a
    second session that subscribes (a recorder, a UI) is seen by zenoh's matching listener and
    gets every message from then on."""
    here, there = two_clients
    key = keys.key(run_id, "qstate")
    with TrioSubscriber(here, key) as local, Publisher(here, run_id, "qstate") as pub:
        for t in range(3):
            pub.put(QState(t, {}, (), {}))
        assert pub.skipped == 3 and not pub.remote
        got: list[int] = []
        handle = there.declare_subscriber(
            key, lambda s: got.append(decode(str(s.key_expr), s.payload.to_bytes()).step))
        with trio.fail_after(10):
            while not pub.remote:  # noqa: ASYNC110 - set by zenoh's matching listener
                await trio.sleep(0.01)
        for t in range(3, 6):
            pub.put(QState(t, {}, (), {}))
        with trio.fail_after(10):
            while len(got) < 3:  # noqa: ASYNC110 - a zenoh callback appends
                await trio.sleep(0.01)
        assert got == [3, 4, 5] and pub.skipped == 3
        assert [r.msg.step for r in local.receive_nowait()] == list(range(6))
        handle.undeclare()
        with trio.fail_after(10):
            while pub.remote:  # noqa: ASYNC110 - gone: no puts again
                await trio.sleep(0.01)
        pub.put(QState(6, {}, (), {}))
        assert pub.skipped == 4


async def test_a_stale_no_from_the_matching_listener_is_corrected_once(two_clients, run_id):
    """The listener's False can lag zenoh's routing (or never change, for a subscription
    declared first); zenoh's own status then says yes, and the publisher keeps that answer
    instead of asking zenoh again at every put (the step chain asked at every qstate)."""
    here, there = two_clients
    key = keys.key(run_id, "qstate")
    got: list[int] = []
    handle = there.declare_subscriber(
        key, lambda s: got.append(decode(str(s.key_expr), s.payload.to_bytes()).step))
    with Publisher(here, run_id, "qstate") as pub:
        with trio.fail_after(10):
            while not pub.matched:  # noqa: ASYNC110 - zenoh's routing
                await trio.sleep(0.01)
        pub.remote = False                      # the listener's stale answer
        pub.put(QState(0, {}, (), {}))
        assert pub.remote and pub.skipped == 0  # asked once, kept
        with trio.fail_after(10):
            while not got:  # noqa: ASYNC110 - a zenoh callback appends
                await trio.sleep(0.01)
        assert got == [0]
    handle.undeclare()


async def test_other_sessions_get_a_locally_handed_message_once(two_clients, run_id):
    here, there = two_clients
    key = keys.key(run_id, "sense")
    with TrioSubscriber(here, key) as local, TrioSubscriber(there, key) as remote, \
            Publisher(here, run_id, "sense") as pub:
        with trio.fail_after(10):
            while not remote.received:          # the other session's subscription is routed
                pub.put(Sense(-1, {}))
                await trio.sleep(0.05)
        await trio.sleep(0.2)
        local.receive_nowait(), remote.receive_nowait()
        for t in range(3):
            pub.put(Sense(t, {"x": 1.0}))
        got: list[int] = []
        with trio.fail_after(10):
            while len(got) < 3:
                got += [r.msg.step for r in await remote.receive_batch()]
        await trio.sleep(0.3)
        assert got == [0, 1, 2]
        assert [r.msg.step for r in local.receive_nowait()] == [0, 1, 2]


async def test_a_hosted_input_gets_foreign_messages_only_and_an_unheard_output_sends_nothing(
        two_clients, run_id):
    """Decision 84. A ``local=False`` subscriber (a hosted actor's input: it takes the chain's
    messages in memory) is not handed its session's published messages but still gets a raw
    put on that session (a forgery, for the rules). An output without a replay log encodes
    nothing while nobody listens (``wanted`` False, counted in ``unsent``) and puts once another
    session subscribes; a logged one always logs."""
    from qlap_runtime.qlap import Params
    from qlap_runtime.runtime.actor import Output
    from qlap_runtime.runtime.context import RunContext

    here, there = two_clients
    key = keys.key(run_id, "motor")
    ctx = RunContext(run_id, "core2d", 10, 0, Params())
    with TrioSubscriber(here, key, local=False) as hosted:
        out, logged = Output(here, ctx, "motor", logged=False), Output(here, ctx, "qstate")
        try:
            assert not out.wanted and logged.wanted
            for t in range(3):
                out.put(t, Motor(t, {"u_x": 0.1}))
                logged.put(t, QState(t, {}, (), {}))
            assert out.unsent == 3 and out.pub.sent == 0
            assert [s for s, _ in logged.log.payloads()] == [0, 1, 2]
            here.put(key, encode(Motor(7, {"u_x": 0.5})))     # raw: not a Publisher's
            with trio.fail_after(10):
                got = await hosted.receive_batch()
            assert [r.msg.step for r in got] == [7]
            remote: list[int] = []
            handle = there.declare_subscriber(
                key, lambda s: remote.append(decode(str(s.key_expr), s.payload.to_bytes()).step))
            with trio.fail_after(10):
                while not out.wanted:  # noqa: ASYNC110 - zenoh's matching listener
                    await trio.sleep(0.01)
            out.put(3, Motor(3, {"u_x": 0.1}))
            with trio.fail_after(10):
                while not remote:  # noqa: ASYNC110 - a zenoh callback appends
                    await trio.sleep(0.01)
            assert remote == [3] and out.unsent == 3
            await trio.sleep(0.2)
            assert hosted.receive_nowait() == []     # the published ones never reach it
            handle.undeclare()
        finally:
            out.close()
            logged.close()


async def test_held_messages_reach_this_session_at_once_and_others_in_one_bundle(
        two_clients, run_id):
    """``hold`` hands a lockstep message to this session's subscribers within the call and
    keeps it for other sessions until ``flush``, which puts all it held as one sample that
    the other session's subscriber hands out message by message, in order (decision 91)."""
    here, there = two_clients
    key = keys.key(run_id, "qstate")
    with TrioSubscriber(here, key) as local, TrioSubscriber(there, key) as remote, \
            Publisher(here, run_id, "qstate") as pub:
        with trio.fail_after(10):
            while not remote.received:          # the other session's subscription is routed
                pub.put(QState(-1, {}, (), {}))
                await trio.sleep(0.05)
        await trio.sleep(0.2)
        local.receive_nowait(), remote.receive_nowait()
        msgs = [QState(t, {"x": t}, (), {"x": 0.5 * t}) for t in range(5)]
        for msg in msgs:
            assert pub.hold(msg)
        assert pub.held == 5 and pub.held_bytes == sum(len(encode(m)) for m in msgs)
        assert [r.msg.step for r in local.receive_nowait()] == [0, 1, 2, 3, 4]
        await trio.sleep(0.3)
        assert remote.receive_nowait() == []    # held: nothing went out yet
        pub.flush()
        assert pub.held == 0 and pub.held_bytes == 0 and pub.bundles == 1
        got: list[QState] = []
        with trio.fail_after(10):
            while len(got) < 5:
                got += [r.msg for r in await remote.receive_batch()]
        assert [m.step for m in got] == [0, 1, 2, 3, 4]
        assert got[3].values == {"x": 3} and got[3].x == {"x": 1.5}
        pub.hold(QState(5, {}, (), {}))         # one held message goes as itself
        pub.flush()
        with trio.fail_after(10):
            last = await remote.receive_batch()
        assert [r.msg.step for r in last] == [5] and pub.bundles == 1
        assert remote.counter.total == 0


async def test_a_flush_in_the_background_keeps_the_order_and_a_flush_waits(two_clients,
                                                                             run_id):
    """``flush(wait=False)`` hands the bundle to the publisher's sender thread and returns;
    the samples go out in the order flushed, before a later :meth:`Publisher.put` and before
    a waiting ``flush()`` returns (docs/decisions.md 96)."""
    here, there = two_clients
    key = keys.key(run_id, "qstate")
    with TrioSubscriber(there, key) as remote, Publisher(here, run_id, "qstate") as pub:
        with trio.fail_after(10):
            while not remote.received:          # the other session's subscription is routed
                pub.put(QState(-1, {}, (), {}))
                await trio.sleep(0.05)
        await trio.sleep(0.2)
        remote.receive_nowait()
        for t in range(12):
            pub.hold(QState(t, {"x": t}, (), {}))
            if t % 3 == 2:
                pub.flush(wait=False)
        pub.put(QState(12, {}, (), {}))         # after every bundle handed to the thread
        pub.hold(QState(13, {}, (), {}))
        pub.flush(wait=False)
        pub.flush()                             # returns once the sender thread is idle
        assert pub.held == 0 and pub.bundles == 4
        assert pub._sender is not None and pub._sender.queue.unfinished_tasks == 0
        got: list[int] = []
        with trio.fail_after(10):
            while len(got) < 14:
                got += [r.msg.step for r in await remote.receive_batch()]
        assert got == list(range(14))
        assert remote.counter.total == 0


async def test_a_bundled_output_sends_at_each_batch_step_and_when_full(two_clients, run_id):
    """A ``bundled`` output (the hosted chain's ``qstate``) holds its messages for other
    sessions and sends them at every batch step (a batch at t reads the steps up to t) and
    once they fill ``BUNDLE_BYTES``; the other session gets every message, in order
    (docs/decisions.md 91)."""
    from qlap_runtime.qlap import Params
    from qlap_runtime.runtime.actor import BUNDLE_BYTES, Output
    from qlap_runtime.runtime.context import RunContext

    here, there = two_clients
    ctx = RunContext(run_id, "core2d", 100, 0, Params(dbn_period=10, landmark_period=20))
    key = keys.key(run_id, "qstate")
    with TrioSubscriber(there, key) as remote:
        out = Output(here, ctx, "qstate", "perception", logged=False, bundled=True)
        try:
            with trio.fail_after(10):
                while not out.pub.wanted:  # noqa: ASYNC110 - zenoh's routing, polled
                    await trio.sleep(0.05)
            for t in range(1, 11):              # 10: a batch step
                out.put(t, QState(t, {"x": 1}, (), {"x": 0.5}))
            assert out.held == 0
            big = {f"v{i}": 0.123456789 * i for i in range(200)}      # ~5 KiB a message
            assert 4_000 < len(encode(QState(11, {}, (), big))) < BUNDLE_BYTES // 4
            for sent in range(11, 31):          # ~100 KiB: never more than the bound held
                out.put(sent, QState(sent, {}, (), big))
                assert out.pub.held_bytes < BUNDLE_BYTES
            sent = 31
            assert out.pub.bundles >= 1          # step 10 at least (time may send more)
            got: list[int] = []
            with trio.fail_after(10):
                while len(got) < sent - 1:
                    got += [r.msg.step for r in await remote.receive_batch()]
            assert got == list(range(1, sent))
        finally:
            out.close()


def test_a_sender_goes_on_after_a_failed_put_and_drains() -> None:
    """A put that raises (the session closing) is logged and dropped; the thread goes on with
    the next samples, in order, and ``drain`` returns (docs/decisions.md 96)."""
    from qlap_runtime.bus.bridge import Sender

    sent: list[int] = []

    def put(sample: int) -> None:
        if sample == 2:
            raise RuntimeError("undeclared publisher")
        sent.append(sample)

    sender = Sender(put, "test")
    for i in range(5):
        sender.send(i)
    sender.drain()
    assert sent == [0, 1, 3, 4]
    sender.close()
    assert not sender.thread.is_alive()
